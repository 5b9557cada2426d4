"""Rules of the flush spots' check against each other that a mutation run found unguarded.

Recipes with few flush spots (``min_flush_spots`` may be as low as 3): the planes are constructed with a known
dZ, dRx, dRy, the readings get a known scatter, then one spot an offset (a seal's, or one set against the
others' prediction computed here by refitting without it).
"""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.inspection import fit_flush
from cellctl.inspection.flush import on_layout

GLASS_XY = np.array([(-260.0, 20.0), (-160.0, 20.0), (-60.0, 20.0), (-20.0, 60.0), (-20.0, 260.0)])
WALL_XY = GLASS_XY + np.array([[0.0, -35.0], [0.0, -35.0], [0.0, -35.0], [35.0, 0.0], [35.0, 0.0]])
DZ, DRX, DRY = 0.2, np.radians(0.02), np.radians(-0.015)  # the truth


def _readings(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    wall_z = 0.05 + 1e-5 * WALL_XY[:, 0] - 2e-5 * WALL_XY[:, 1]
    glass_z = 0.05 + 1e-5 * GLASS_XY[:, 0] - 2e-5 * GLASS_XY[:, 1] + DZ + DRX * GLASS_XY[:, 1] - DRY * GLASS_XY[:, 0]
    g = np.column_stack([GLASS_XY, glass_z + rng.normal(0.0, 0.005, len(GLASS_XY))])
    w = np.column_stack([WALL_XY, wall_z + rng.normal(0.0, 0.005, len(WALL_XY))])
    return g, w


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_with_five_spots_a_reading_off_its_surface_is_still_left_out_and_named(seed: int) -> None:
    g, w = _readings(seed)
    g[1, 2] += 0.4  # a seal under the beam at the middle top spot
    # It drags the others' plane so the end spot (-260, 20) reads past its own limit too: the worst is left out
    # first, and checked again without it, the end spot is fine.
    f = fit_flush(g, w, max_rms_mm=0.15, outlier_mm=0.1)
    assert [(r.index, r.surface) for r in f.rejected] == [(1, "glass")]
    assert f.dz_mm == pytest.approx(DZ, abs=0.02)  # fitted with the seal's spot: 0.1 mm or more off, or refused



# A recipe's L of near spots with one more along the top, 240 mm past the others (still verifiable: its
# neighbours predict its step with about twice one step's scatter).
L_GLASS = np.array([(-260.0, 20.0), (-210.0, 20.0), (-160.0, 20.0), (-110.0, 20.0), (-60.0, 20.0), (-20.0, 60.0),
                    (-20.0, 110.0), (-20.0, 160.0), (-500.0, 20.0)])  # fmt: skip
L_WALL = L_GLASS + np.where(L_GLASS[:, 1:] == 20.0, [0.0, -35.0], [35.0, 0.0])


def _l_readings(seed: int, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Glass at the true dZ, dRx, dRy over a flat wall, each reading with ``sigma`` of the robot's repeatability."""
    rng = np.random.default_rng(seed)
    glass_z = DZ + DRX * L_GLASS[:, 1] - DRY * L_GLASS[:, 0]
    g = np.column_stack([L_GLASS, glass_z + rng.normal(0.0, sigma, len(L_GLASS))])
    w = np.column_stack([L_WALL, rng.normal(0.0, sigma, len(L_WALL))])
    return g, w


def _set_step_off_the_others(g: np.ndarray, w: np.ndarray, k: int, times_limit: float) -> float:
    """Move spot k's glass reading so its step lies ``times_limit`` of its limit (OUTLIER_K prediction sigmas) off the
    plane refitted by least squares to the other spots' steps; the limit computed here, independently. Returns it."""
    steps = g[:, 2] - w[:, 2]
    X = np.column_stack([np.ones(len(g)), g[:, :2]])
    m = np.arange(len(g)) != k
    c, *_ = np.linalg.lstsq(X[m], steps[m], rcond=None)
    r = steps[m] - X[m] @ c
    s = float(np.sqrt(r @ r / (m.sum() - 3)))
    sigma = s * float(np.sqrt(1.0 + X[k] @ np.linalg.inv(X[m].T @ X[m]) @ X[k]))  # the prediction's sigma at spot k
    g[k, 2] = w[k, 2] + X[k] @ c + times_limit * 4.0 * sigma
    return 4.0 * sigma


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_far_spot_is_judged_by_how_well_the_others_predict_it_there(seed: int) -> None:
    """Inside four sigmas of the others' prediction at its place it is kept, beyond them it is left out: the
    prediction is looser there than one step's scatter (the others' plane is extrapolated 240 mm)."""
    g, w = _l_readings(seed, 0.04)
    limit = _set_step_off_the_others(g, w, 8, 0.9)
    assert limit > 0.15  # far above the 0.1 mm floor: the others' scatter sets it
    assert fit_flush(g, w, max_rms_mm=0.3, outlier_mm=0.1).rejected == ()
    _set_step_off_the_others(g, w, 8, 1.1)
    assert [r.index for r in fit_flush(g, w, max_rms_mm=0.3, outlier_mm=0.1).rejected] == [8]


def test_a_missing_spot_without_which_a_tilt_is_known_half_as_well_marks_the_result_unreliable() -> None:
    # Without the spot 240 mm along the top, dRy rests on the five near top spots' 200 mm: its sigma doubles
    # (computed here from the layouts alone). The flush from the other eight is measured, and marked unreliable.
    def tilt_sigmas(xy: np.ndarray) -> np.ndarray:
        X = np.column_stack([np.ones(len(xy)), xy])
        return np.sqrt(np.diag(np.linalg.inv(X.T @ X)))[1:]

    assert tilt_sigmas(L_GLASS[:8])[0] > 2.0 * tilt_sigmas(L_GLASS)[0]
    g, w = _l_readings(1, 0.01)
    used = list(range(8))
    f = on_layout(fit_flush(g[used], w[used], max_rms_mm=0.15, outlier_mm=0.1, spots=used), used, L_GLASS)
    assert f.unreliable is not None and "[8]" in f.unreliable
    assert on_layout(fit_flush(g, w, max_rms_mm=0.15, outlier_mm=0.1), range(9), L_GLASS).unreliable is None
