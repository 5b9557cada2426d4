"""Each flush spot checked against the others: a stray glass or wall reading is left out and named, not fitted.

The planes are constructed with a known dZ, dRx, dRy over the default spot layout; the readings get 0.01 mm
of scatter, then one of them a seal's or a reflection's offset.
"""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config.inspection import InspectionConfig
from cellctl.inspection import FlushError, fit_flush
from cellctl.inspection.flush import on_layout
from cellctl.inspection.flush_outliers import deleted_fit, tilt_setting_spots

SPOTS = InspectionConfig().flush_spots
GLASS_XY = np.array([s.glass_mm for s in SPOTS])
WALL_XY = np.array([s.wall_mm for s in SPOTS])
DZ, DRX, DRY = 0.2, np.radians(0.02), np.radians(-0.015)  # the truth
FLOOR = InspectionConfig().flush_outlier_mm


def _readings(seed: int, sigma: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Glass at z = DZ + DRX y - DRY x over a wall tilted a little in T2 (both with scatter)."""
    rng = np.random.default_rng(seed)
    wall_z = 0.05 + 1e-5 * WALL_XY[:, 0] - 2e-5 * WALL_XY[:, 1]
    glass_z = 0.05 + 1e-5 * GLASS_XY[:, 0] - 2e-5 * GLASS_XY[:, 1] + DZ + DRX * GLASS_XY[:, 1] - DRY * GLASS_XY[:, 0]
    g = np.column_stack([GLASS_XY, glass_z + rng.normal(0.0, sigma, len(SPOTS))])
    w = np.column_stack([WALL_XY, wall_z + rng.normal(0.0, sigma, len(SPOTS))])
    return g, w


def _fit(g: np.ndarray, w: np.ndarray, **kw: object):  # type: ignore[no-untyped-def]
    return fit_flush(g, w, max_rms_mm=0.15, outlier_mm=FLOOR, **kw)  # type: ignore[arg-type]


@pytest.mark.parametrize("k, surface, off", [(0, "glass", 0.3), (4, "glass", -0.3), (7, "wall", 0.3), (2, "wall", -0.5)])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_near_reading_off_its_surface_is_left_out_and_named(k: int, surface: str, off: float, seed: int) -> None:
    g, w = _readings(seed)
    (g if surface == "glass" else w)[k, 2] += off
    f = _fit(g, w)
    assert [(r.index, r.surface) for r in f.rejected] == [(k, surface)]
    assert f.rejected[0].off_mm == pytest.approx(off if surface == "glass" else -off, abs=0.06)
    assert f.dz_mm == pytest.approx(DZ, abs=0.015)


@pytest.mark.parametrize("k, off", [(10, 1.0), (11, 1.0), (11, 2.0), (10, -0.5)])
def test_a_far_reading_off_is_kept_and_named_unverifiable(k: int, off: float) -> None:
    """A spot that alone sets a tilt cannot be checked by the near ones (in a real cell the robot's accuracy differs
    more between far places than their scatter says): it is kept, and named with what the check could not see."""
    g, w = _readings(1)
    g[k, 2] += off
    f = on_layout(_fit(g, w), range(len(SPOTS)), GLASS_XY)
    assert not f.rejected and k in [u.index for u in f.unverifiable]


def test_normal_scatter_rejects_no_spot() -> None:
    for seed in range(400):
        f = on_layout(_fit(*_readings(seed)), range(len(SPOTS)), GLASS_XY)
        assert not f.rejected and f.unreliable is None, f"seed {seed}: {f.rejected}"
        assert [u.index for u in f.unverifiable] == [10, 11]
        assert all(u.detects_above_mm is not None and u.detects_above_mm >= FLOOR for u in f.unverifiable)


def test_the_floor_keeps_a_near_perfect_fit_from_rejecting_a_small_step() -> None:
    g, w = _readings(1, sigma=0.0)
    g[3, 2] += 0.8 * FLOOR
    assert _fit(g, w).rejected == ()
    g[3, 2] += 0.4 * FLOOR
    assert [r.index for r in _fit(g, w).rejected] == [3]


def test_too_few_spots_left_refuse_with_the_spot_named() -> None:
    g, w = _readings(2)
    g[5, 2] += 0.4
    with pytest.raises(FlushError, match=r"spot 105 \(glass, \+0\.4"):
        _fit(g, w, min_spots=12, spots=[100 + i for i in range(12)])


def test_a_missing_far_spot_marks_the_result_unreliable() -> None:
    assert tilt_setting_spots(GLASS_XY) == [10, 11]
    keep = [i for i in range(12) if i != 11]
    g, w = _readings(3)
    f = on_layout(_fit(g[keep], w[keep], spots=keep), keep, GLASS_XY)
    assert f.unreliable is not None and "[11]" in f.unreliable
    assert on_layout(_fit(*_readings(3)), range(12), GLASS_XY).unreliable is None


def test_the_deleted_residuals_match_refitting_without_each_spot() -> None:
    """The closed form against the plane refitted by least squares without the spot (an independent peer)."""
    g, _ = _readings(4, sigma=0.03)
    d = deleted_fit(g[:, :2], g[:, 2])
    X = np.column_stack([np.ones(len(g)), g[:, :2]])
    for i in range(len(g)):
        m = np.arange(len(g)) != i
        c, *_ = np.linalg.lstsq(X[m], g[m, 2], rcond=None)
        r = g[m, 2] - X[m] @ c
        assert d.residual[i] == pytest.approx(g[i, 2] - X[i] @ c, abs=1e-9)
        assert d.scale[i] == pytest.approx(np.sqrt(r @ r / (m.sum() - 3)), rel=1e-6)
        assert d.inflation[i] == pytest.approx(np.sqrt(1 + X[i] @ np.linalg.inv(X[m].T @ X[m]) @ X[i]), rel=1e-6)
