"""The flush on the move, from the steps where single legs cross an edge, against a glass at a known pose.

Readings are made along the default sweep path as a moving robot gives them: each leg carries its
own error (its ends' repeatability errors blended along the leg, a deflection that grows and falls
with the leg's speed, a curvature of the accuracy field), the laser adds its noise.
"""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from cellctl.config.inspection import InspectionConfig
from cellctl.geometry.pose import make_pose
from cellctl.geometry.rotation import xyz_fixed_to_matrix
from cellctl.inspection import FlushError, fit_flush
from cellctl.inspection.flush_crossing import (
    EdgeCrossing,
    crossing_legs,
    fit_flush_across_edges,
    flush_from_sweep,
    step_across_edge,
    surface_at,
)
from cellctl.sim.truth import score_glass

CFG = InspectionConfig()
GAP, MARGIN = CFG.nominal_gap_mm, CFG.sweep_margin_mm


def _glass_pose(dz: float, drx_deg: float, dry_deg: float) -> np.ndarray:
    R = xyz_fixed_to_matrix(np.radians(0.02), np.radians(dry_deg), np.radians(drx_deg))
    return make_pose(R, [0.12, -0.08, dz])


def _height(E: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """z in T of the glass's surface (z = 0 in its frame E) over the points xy; the wall is z = 0."""
    n, p0 = E[:3, 2], E[:3, 3]
    return (n @ p0 - n[0] * xy[:, 0] - n[1] * xy[:, 1]) / n[2]


def _sweep(E: np.ndarray, path: np.ndarray, rng: np.random.Generator, *, leg_sigma_mm: float = 0.03,
           deflection_mm: float = 0.03, curvature_mm: float = 0.02) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Readings (K, 3) in T and their leg indices along ``path``: each leg's own robot error, laser noise."""
    points, legs = [], []
    ends = rng.normal(0.0, leg_sigma_mm, len(path))  # a fresh repeatability error at every corner
    for j, (a, b) in enumerate(zip(path, path[1:])):
        f = np.linspace(0.0, 1.0, max(int(np.linalg.norm(b - a) / 3.0), 2))
        xy = a + f[:, None] * (b - a)
        error = ends[j] + (ends[j + 1] - ends[j]) * f  # the ends' errors blended along the leg
        error += deflection_mm * (1.0 - np.abs(2.0 * f - 1.0))  # grows and falls with a short leg's speed
        error += curvature_mm * (2.0 * f - 1.0) ** 2 * rng.choice([-1.0, 1.0])  # the accuracy field's curvature
        s = surface_at(xy, GAP, MARGIN)
        z = np.where(s > 0, _height(E, xy), 0.0) + error
        z += rng.normal(0.0, 0.003, len(f))
        points.append(np.column_stack([xy, z]))
        legs.append(np.full(len(f), j))
    return np.concatenate(points), np.concatenate(legs)


@pytest.mark.parametrize("dz, drx, dry", [(0.0, 0.0, 0.0), (0.35, 0.02, -0.015), (-0.4, -0.03, 0.03)])
def test_the_steps_across_the_edges_give_the_glass_pose_through_each_legs_own_error(dz: float, drx: float, dry: float) -> None:
    E = _glass_pose(dz, drx, dry)
    truth = score_glass(E, np.eye(4))
    path = np.array(CFG.sweep_path_mm)
    rng = np.random.default_rng(int(1000 * (dz + 1)))
    dz_off, planes_off = [], []
    for _ in range(20):
        points, legs = _sweep(E, path, rng)
        f, crossings = flush_from_sweep(points, legs, path, gap_mm=GAP, margin_mm=MARGIN, max_rms_mm=0.15)
        dz_off.append(f.dz_mm - truth.dz_mm)
        assert np.degrees(f.drx_rad) == pytest.approx(truth.drx_deg, abs=2e-3)
        assert np.degrees(f.dry_rad) == pytest.approx(truth.dry_deg, abs=2e-3)
        assert len(crossings) == len(f.flush_mm) == 4 and f.dz_sigma_mm < 0.005
        # the same readings as two planes (glass and wall, each over every leg) carry the legs' errors
        s = surface_at(points[:, :2], GAP, MARGIN)
        planes = fit_flush(points[s > 0], points[s < 0], max_rms_mm=1.0)
        planes_off.append(planes.dz_mm - truth.dz_mm)
    rms, rms_planes = float(np.sqrt(np.mean(np.square(dz_off)))), float(np.sqrt(np.mean(np.square(planes_off))))
    assert rms < 0.006, dz_off  # the laser's noise, extrapolated over the gap
    assert rms_planes > 3 * rms, planes_off  # what reading glass and wall on one leg takes out


def test_mirrored_windows_cancel_an_error_even_about_the_legs_middle() -> None:
    # A leg centred on the gap whose wall readings stop short (the rest unreadable), under an error curved
    # about the leg's middle (the accuracy field's curvature): lines over unequal stretches would not agree there.
    a, b = np.array([-300.0, 47.5]), np.array([-250.0, -42.5])
    f = np.linspace(0.0, 1.0, 400)
    xy = a + f[:, None] * (b - a)
    s = surface_at(xy, GAP, MARGIN)
    z = np.where(s > 0, 0.2, 0.0) + 2e-4 * (np.linalg.norm(b - a) * (f - 0.5)) ** 2
    keep = (s != 0) & (f < 0.8)
    c = step_across_edge(np.column_stack([xy, z])[keep], s[keep] > 0, a, b, max_rms_mm=0.15)
    assert c.step_mm == pytest.approx(0.2, abs=1e-9)
    assert (c.x_mm, c.y_mm) == pytest.approx((-275.0, 2.5))
    assert c.glass_readings == pytest.approx(c.wall_readings, abs=1)
    off_centre = np.column_stack([xy, z])[(s != 0)]
    with pytest.raises(FlushError, match="centre each crossing leg on the gap"):
        step_across_edge(off_centre, s[s != 0] > 0, a, np.array([-250.0, -102.5]), max_rms_mm=0.15)


def test_a_leg_that_crosses_twice_or_reads_one_side_too_little_is_refused() -> None:
    a, b = np.array([-300.0, 25.0]), np.array([-100.0, -20.0])
    xy = a + np.linspace(0, 1, 60)[:, None] * (b - a)
    z = np.zeros(len(xy))
    glass = np.arange(len(xy)) % 2 == 0  # glass and wall readings alternate along the leg
    with pytest.raises(FlushError, match="crosses more than one edge"):
        step_across_edge(np.column_stack([xy, z]), glass, a, b, max_rms_mm=0.15)
    with pytest.raises(FlushError, match="glass readings on the leg"):
        step_across_edge(np.column_stack([xy, z])[:40], np.arange(40) < 2, a, b, max_rms_mm=0.15)


def test_crossings_on_one_edge_alone_leave_the_tilt_across_it_unknown() -> None:
    c = [EdgeCrossing(x, 2.5, 0.1, 0.001, 10, 10, 0.002, 0.002) for x in (-1700.0, -900.0, -250.0)]
    with pytest.raises(FlushError, match="on one line"):
        fit_flush_across_edges(c, max_rms_mm=0.15)
    with pytest.raises(FlushError, match="at least 3"):
        fit_flush_across_edges(c[:2], max_rms_mm=0.15)
    bent = [*c[:2], EdgeCrossing(-2.5, 250.0, 0.1, 0.001, 10, 10, 0.002, 0.002), EdgeCrossing(-2.5, 1200.0, 0.9, 0.001, 10, 10, 0.002, 0.002)]
    with pytest.raises(FlushError, match="do not lie on one plane"):
        fit_flush_across_edges([*bent, EdgeCrossing(-2.5, 700.0, 0.1, 0.001, 10, 10, 0.002, 0.002)], max_rms_mm=0.15)


def test_the_default_path_crosses_both_edges_near_and_far_and_a_path_along_the_edges_is_refused() -> None:
    middles = [tuple((a + b) / 2) for _, a, b in crossing_legs(CFG.sweep_path_mm, GAP, MARGIN)]
    assert middles == [(-250.0, 2.5), (-2.5, 250.0), (-2.5, 1200.0), (-1700.0, 2.5)]
    along_the_edges = [(-60.0, -15.0), (-1700.0, -15.0), (-1700.0, 20.0), (-60.0, 20.0),
                       (-20.0, 60.0), (-20.0, 1200.0), (15.0, 1200.0), (15.0, 60.0)]  # fmt: skip
    with pytest.raises(ValidationError, match="sweep_path_mm crosses an edge on 2 legs"):
        InspectionConfig(sweep_path_mm=along_the_edges)
    off_gap = [(-350.0, -20.0), (-150.0, 45.0), (-25.0, 150.0), (20.0, 350.0), (20.0, 1100.0), (-25.0, 1300.0)]
    with pytest.raises(ValidationError, match=r"middles \[\[-250.0, 12.5\]\] lie outside the gap"):
        InspectionConfig(sweep_path_mm=off_gap)
