"""Rules of the flush on the move that a mutation run found unguarded: the crossings' layout (a base for each
tilt, not on one line), the mirrored window's count per side, a crossing's sigma and its capped weight.

The steps are built from a known glass plane (``step = dZ - dRy x + dRx y``) or from readings with a known
step and known noise, so every expected figure is the construction's, not the code's.
"""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.inspection import FlushError
from cellctl.inspection.flush_crossing import EdgeCrossing, fit_flush_across_edges, step_across_edge

DZ, DRX, DRY = 0.2, 2e-4, -1.5e-4  # the truth: mm, rad, rad


def _crossings(at: list[tuple[float, float]], sigma_mm: float = 0.002) -> list[EdgeCrossing]:
    """Crossings at ``at`` whose steps lie exactly on the true glass plane."""
    return [EdgeCrossing(x, y, DZ - DRY * x + DRX * y, sigma_mm, 20, 20, 0.003, 0.003) for x, y in at]


def test_crossings_close_to_the_corner_on_one_edge_give_no_base_for_its_tilt_and_are_refused() -> None:
    # The same plane read at the default layout's crossings comes back exact ...
    wide = fit_flush_across_edges(_crossings([(-250.0, 2.5), (-2.5, 250.0), (-2.5, 1200.0), (-1700.0, 2.5)]), max_rms_mm=0.15)
    assert (wide.dz_mm, wide.drx_rad, wide.dry_rad) == pytest.approx((DZ, DRX, DRY), abs=1e-9)
    # ... but with the side edge crossed only 60 mm below the corner, dRx rests on a 57.5 mm base: a 5 um
    # error in one step would tilt the glass by 0.005 deg. The crossings are not on one line; they are refused.
    narrow = _crossings([(-250.0, 2.5), (-1700.0, 2.5), (-2.5, 60.0)])
    with pytest.raises(FlushError, match="span 1698 mm in x and 58 mm in y"):
        fit_flush_across_edges(narrow, max_rms_mm=0.15)


def test_crossings_on_one_slanted_line_leave_the_tilt_across_it_unknown_and_are_refused() -> None:
    # Each span is 400 mm, yet the three points lie on y = x + 402.5: the plane may turn about that line freely.
    on_a_line = _crossings([(-400.0, 2.5), (-200.0, 202.5), (-2.5, 400.0)])
    with pytest.raises(FlushError, match="not on one line"):
        fit_flush_across_edges(on_a_line, max_rms_mm=0.15)
    with pytest.raises(FlushError, match="not on one line"):
        fit_flush_across_edges([*on_a_line, *_crossings([(-300.0, 102.5)])], max_rms_mm=0.15)


def test_a_crossing_whose_mirrored_window_keeps_too_few_readings_on_one_side_is_refused() -> None:
    # A leg straight down across the top edge, its middle (s = 40 mm) in the gap. The wall's readings next to the
    # gap are lost (a dark seal): only 7 far ones remain, 35 to 38 mm past the middle. Mirrored about the middle,
    # the glass keeps only its readings 35 to 38 mm before it: 3, too few for a model of five terms.
    a, b = np.array([-200.0, 42.5]), np.array([-200.0, -37.5])
    s_glass = np.arange(2.0, 36.5, 1.5)
    s_wall = np.arange(75.0, 78.01, 0.5)
    s = np.concatenate([s_glass, s_wall])
    xy = a + s[:, None] * (b - a) / np.linalg.norm(b - a)
    on_glass = np.arange(len(s)) < len(s_glass)
    z = np.where(on_glass, 0.1, 0.0)
    assert len(s_glass) >= 4 and len(s_wall) >= 4 and np.count_nonzero(np.abs(s_glass - 40.0) >= 35.0) == 3
    with pytest.raises(FlushError, match="keeps too few readings in its mirrored window"):
        step_across_edge(np.column_stack([xy, z]), on_glass, a, b, max_rms_mm=0.15)


def test_a_crossings_sigma_is_the_scatter_its_step_shows_over_repeated_legs() -> None:
    # The same leg read 400 times with 3 um of laser noise: the steps' own scatter is the independent measure.
    rng = np.random.default_rng(7)
    a, b = np.array([-300.0, 25.0]), np.array([-100.0, -20.0])
    f = np.linspace(0.0, 1.0, 200)
    xy = a + f[:, None] * (b - a)
    on_glass = xy[:, 1] > 11.0  # the glass inside its edge and the margin, the wall outside the opening's
    wall = xy[:, 1] < -6.0
    keep = on_glass | wall
    steps, sigmas = [], []
    for _ in range(400):
        z = np.where(on_glass, 0.1, 0.0) + rng.normal(0.0, 0.003, len(f))
        c = step_across_edge(np.column_stack([xy, z])[keep], on_glass[keep], a, b, max_rms_mm=0.15)
        steps.append(c.step_mm)
        sigmas.append(c.sigma_mm)
    scatter = float(np.std(steps, ddof=1))
    assert float(np.mean(steps)) == pytest.approx(0.1, abs=3 * scatter / np.sqrt(len(steps)) + 1e-6)
    assert float(np.sqrt(np.mean(np.square(sigmas)))) == pytest.approx(scatter, rel=0.15)


def test_a_crossing_that_fits_its_readings_too_well_counts_no_more_than_the_cap() -> None:
    # Five crossings on the true plane, the middle top one 0.03 mm off through an error its lines' scatter cannot see
    # (the leg's robot error), its readings fitting to 1e-6 mm. Capped at MIN_STEP_SIGMA_MM (as the others'
    # 0.001 mm) it weighs as they do: ordinary least squares, whose pull on dZ the construction gives.
    at = [(-250.0, 2.5), (-2.5, 250.0), (-2.5, 1200.0), (-1700.0, 2.5), (-900.0, 2.5)]
    crossings = _crossings(at, sigma_mm=0.001)
    x, y = at[4]
    crossings[4] = EdgeCrossing(x, y, DZ - DRY * x + DRX * y + 0.03, 1e-6, 20, 20, 0.003, 0.003)
    A = np.array([[1.0, -x, y] for x, y in at])
    steps = np.array([c.step_mm for c in crossings])
    ols = np.linalg.lstsq(A, steps, rcond=None)[0]  # equal weights: the cap's answer, computed independently
    f = fit_flush_across_edges(crossings, max_rms_mm=0.15)
    assert (f.dz_mm, f.dry_rad, f.drx_rad) == pytest.approx(tuple(ols), abs=1e-9)
    assert abs(f.dz_mm - DZ) < 0.012  # 0.007 mm; uncapped, the plane would pass through the off crossing: 0.023 mm
