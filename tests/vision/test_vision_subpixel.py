"""The area estimator of edge crossings: no sub-pixel phase bias, lighting cancels, noise averages."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr

from cellctl.vision.subpixel import measure_crossings


def _pixel_integrated_step(rows: np.ndarray, edge: np.ndarray, sigma: float) -> np.ndarray:
    """Share of each pixel [r - 1/2, r + 1/2] beyond the Gaussian-blurred step at ``edge``."""

    def integral(x: np.ndarray) -> np.ndarray:
        z = (x - edge) / sigma
        return sigma * (z * ndtr(z) + np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi))

    return integral(rows + 0.5) - integral(rows - 0.5)


def _image(edge: np.ndarray, sigma: float, *, lo: float = 20.0, hi: float = 150.0, ramp: float = 0.0) -> np.ndarray:
    rows = np.arange(64, dtype=float)[:, None]
    f = _pixel_integrated_step(rows, edge[None, :], sigma)
    return lo + (hi - lo) * f + ramp * (rows - edge[None, :])


@pytest.mark.parametrize("sigma", [0.5, 0.8, 1.5, 3.0])
def test_no_phase_bias_for_any_blur(sigma: float) -> None:
    edge = 30.0 + np.linspace(0.0, 1.0, 101)  # every sub-pixel phase
    img = _image(edge, sigma)
    rng = np.random.default_rng(0)
    r = measure_crossings(
        img, np.arange(101), edge + rng.uniform(-2, 2, 101), along_rows=False, search_px=3.0,
        level_samples=2, max_blur_sigma_px=4.0,
    )
    assert r.valid.all()
    assert np.max(np.abs(r.position - edge)) < 2e-3
    assert np.median(r.blur_sigma_px) == pytest.approx(np.hypot(sigma, np.sqrt(1 / 12)), rel=0.15)
    assert np.all(r.contrast == pytest.approx(130.0, abs=0.5))


def test_a_background_ramp_cancels_to_first_order() -> None:
    edge = 30.0 + np.linspace(0.0, 1.0, 101)
    img = _image(edge, 0.8, ramp=1.2)  # 1.2 DN/px: the flank of a strong glare spot
    r = measure_crossings(
        img, np.arange(101), edge + 1.0, along_rows=False, search_px=3.0, level_samples=2, max_blur_sigma_px=4.0
    )
    assert abs(np.mean(r.position - edge)) < 2e-3
    assert np.max(np.abs(r.position - edge)) < 0.03


def test_noise_averages_and_rows_work_like_columns() -> None:
    rng = np.random.default_rng(5)
    edge = 30.0 + rng.uniform(0, 1, 2000)
    img = np.clip(np.rint(_image(edge, 0.8) + rng.normal(0, 2.3, (64, 2000))), 0, 255).astype(np.uint8)
    r = measure_crossings(
        img.T.copy(), np.arange(2000), edge + rng.uniform(-2, 2, 2000), along_rows=True, search_px=3.0,
        level_samples=2, max_blur_sigma_px=4.0,
    )
    err = r.position - edge
    assert r.valid.all()
    assert abs(err.mean()) < 0.01
    assert 0.04 < err.std() < 0.15


def test_profiles_off_the_image_or_without_a_crossing_are_invalid() -> None:
    edge = np.full(4, 30.3)
    img = _image(edge, 0.8)
    r = measure_crossings(
        img, np.arange(4), np.array([30.0, 2.0, 61.0, 30.0]), along_rows=False, search_px=3.0,
        level_samples=2, max_blur_sigma_px=4.0,
    )
    assert r.valid.tolist() == [True, False, False, True]
    flat = np.full((64, 3), 100.0)
    flat[:, 1] = 255.0
    r = measure_crossings(
        flat.astype(np.uint8), np.arange(3), np.full(3, 30.0), along_rows=False, search_px=3.0, level_samples=2,
        max_blur_sigma_px=4.0,
    )
    assert np.all(np.abs(r.contrast) < 1e-9)
    assert r.saturated.tolist() == [False, True, False]


@pytest.mark.parametrize(("rows", "line_dn"), [((33, 35), 5.0), ((26, 28), 240.0)])
def test_a_mark_inside_the_window_leaves_its_profile_out(rows: tuple[int, int], line_dn: float) -> None:
    # A 2 px line 3 px from the edge (inside every window, not at its ends) on half the columns,
    # dark on the bright side or bright on the dark side: without the check those crossings move
    # by a pixel or more and look valid.
    edge = np.full(60, 30.3)
    img = _image(edge, 0.8)
    img[rows[0] : rows[1], :30] = line_dn
    r = measure_crossings(
        img, np.arange(60), edge + 0.4, along_rows=False, search_px=3.0, level_samples=2, max_blur_sigma_px=4.0
    )
    assert not r.valid[:30].any()
    assert r.valid[30:].all() and np.max(np.abs(r.position[30:] - 30.3)) < 2e-3


def test_noise_on_a_faint_edge_does_not_thin_its_profiles() -> None:
    # A 16 DN edge with 2 DN noise: the allowance grows with the plateaus' noise, so the profiles stay.
    edge = np.full(400, 30.0)
    rng = np.random.default_rng(4)
    img = _image(edge, 0.8, lo=20.0, hi=36.0) + rng.normal(0.0, 2.0, (64, 400))
    r = measure_crossings(
        img, np.arange(400), edge, along_rows=False, search_px=3.0, level_samples=2, max_blur_sigma_px=4.0
    )
    assert r.valid.mean() > 0.9
