"""The flush on the move, from the steps where single legs cross an edge, against a glass at a known pose.

Readings are made along the default sweep path as a moving robot gives them: each leg carries its
own error (its ends' repeatability errors blended along the leg, a deflection that grows and falls
with the leg's speed, a curvature of the accuracy field), the laser adds its noise.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
from cellctl.config.inspection import InspectionConfig
from cellctl.config.loader import ConfigError, parse_config
from cellctl.geometry.pose import make_pose
from cellctl.geometry.rotation import xyz_fixed_to_matrix
from cellctl.inspection import FlushError, fit_flush
from cellctl.inspection.flush_crossing import (
    EdgeCrossing,
    crossing_legs,
    crossing_path_problem,
    fit_flush_across_edges,
    flush_from_sweep,
    step_across_edge,
    surface_at,
)
from cellctl.sim.truth import score_glass

ROOT = Path(__file__).resolve().parents[2]
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
        f, crossings, missing = flush_from_sweep(points, legs, path, gap_mm=GAP, margin_mm=MARGIN, max_rms_mm=0.15)
        dz_off.append(f.dz_mm - truth.dz_mm)
        assert np.degrees(f.drx_rad) == pytest.approx(truth.drx_deg, abs=2e-3)
        assert np.degrees(f.dry_rad) == pytest.approx(truth.dry_deg, abs=2e-3)
        assert len(crossings) == len(f.flush_mm) == 4 and not missing and f.dz_sigma_mm < 0.005
        # the same readings as two planes (glass and wall, each over every leg) carry the legs' errors
        s = surface_at(points[:, :2], GAP, MARGIN)
        planes = fit_flush(points[s > 0], points[s < 0], max_rms_mm=1.0)
        planes_off.append(planes.dz_mm - truth.dz_mm)
    rms, rms_planes = float(np.sqrt(np.mean(np.square(dz_off)))), float(np.sqrt(np.mean(np.square(planes_off))))
    assert rms < 0.006, dz_off  # the laser's noise, extrapolated over the gap
    assert rms_planes > 3 * rms, planes_off  # what reading glass and wall on one leg takes out


def test_mirrored_windows_cancel_an_error_even_about_the_legs_middle() -> None:
    # A leg centred on the gap whose wall readings stop short (the rest unreadable), under an error even about
    # the leg's middle but beyond the model's |x| and x^2: fitted over unequal stretches it would leak into the step.
    a, b = np.array([-300.0, 47.5]), np.array([-250.0, -42.5])
    f = np.linspace(0.0, 1.0, 400)
    xy = a + f[:, None] * (b - a)
    s = surface_at(xy, GAP, MARGIN)
    z = np.where(s > 0, 0.2, 0.0) + 2e-6 * np.abs(np.linalg.norm(b - a) * (f - 0.5)) ** 3
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
    side = [EdgeCrossing(-2.5, y, step, 0.001, 10, 10, 0.002, 0.002) for y, step in ((250.0, 0.1), (1200.0, 0.9))]
    bent = [*c[:2], *side]
    with pytest.raises(FlushError, match="do not lie on one plane"):
        fit_flush_across_edges([*bent, EdgeCrossing(-2.5, 700.0, 0.1, 0.001, 10, 10, 0.002, 0.002)], max_rms_mm=0.15)


def test_a_crossing_without_its_readings_is_left_out_while_the_rest_span_both_edges() -> None:
    E = _glass_pose(0.2, 0.01, -0.01)
    truth = score_glass(E, np.eye(4))
    path = np.array(CFG.sweep_path_mm)
    points, legs = _sweep(E, path, np.random.default_rng(5))
    legs[legs == 0] = -1  # the near top crossing's readings lost (no distance off a dark seal)
    f, crossings, missing = flush_from_sweep(points, legs, path, gap_mm=GAP, margin_mm=MARGIN, max_rms_mm=0.15)
    assert len(crossings) == 3 and len(missing) == 1 and missing[0].startswith("leg 0: 0 glass readings"), missing
    assert f.dz_mm == pytest.approx(truth.dz_mm, abs=0.01)
    legs[legs == 4] = -1  # and the far side's: two are left
    with pytest.raises(FlushError, match="2 edge crossings; the flush's plane needs at least 3.*; leg 0: .*; leg 4: "):
        flush_from_sweep(points, legs, path, gap_mm=GAP, margin_mm=MARGIN, max_rms_mm=0.15)


@pytest.mark.parametrize("phase_s", [0.0, 0.003, 0.006])
def test_the_deflection_of_a_legs_speed_profile_cancels_however_the_readings_fall(phase_s: float) -> None:
    # A 0.2 mm deflection at the leg's top speed, growing and falling with it (triangular speed profile, the
    # readings every 10 ms at a phase of their own, one lost on the glass): curved in x, even about the middle.
    a, b = np.array([-350.0, -20.0]), np.array([-150.0, 25.0])
    length, acc = float(np.linalg.norm(b - a)), 2000.0
    T = 2.0 * np.sqrt(length / acc)
    t = np.arange(phase_s, T, 0.01)
    along = np.where(t < T / 2, 0.5 * acc * t**2, length - 0.5 * acc * (T - t) ** 2)
    speed = np.where(t < T / 2, acc * t, acc * (T - t))
    xy = a + (along / length)[:, None] * (b - a)
    s = surface_at(xy, GAP, MARGIN)
    z = np.where(s > 0, 0.05, 0.0) + 0.2 * speed / speed.max()
    keep = s != 0
    glass = np.flatnonzero(s > 0)
    keep[glass[len(glass) // 2]] = False
    c = step_across_edge(np.column_stack([xy, z])[keep], s[keep] > 0, a, b, max_rms_mm=0.15)
    assert c.step_mm == pytest.approx(0.05, abs=0.002)  # a line each side: off by 0.008 to 0.013 mm


def test_windows_mirrored_inside_too_cancel_the_deflection_of_a_leg_whose_middle_is_off_the_gaps_centre() -> None:
    # The leg's middle on the opening's edge (y = 0, not the gap's centre 2.5): the readings next to the gap
    # start 6 mm before the middle on one side and 11 mm after it on the other; the deflection that grows
    # and falls with the leg's speed (even about its middle) only cancels if the inner ends are mirrored too.
    a, b = np.array([-300.0, 22.5]), np.array([-100.0, -22.5])
    f = np.linspace(0.0, 1.0, 300)
    xy = a + f[:, None] * (b - a)
    s = surface_at(xy, GAP, MARGIN)
    z = np.where(s > 0, 0.1, 0.0) + 0.06 * np.sqrt(1.0 - np.abs(2.0 * f - 1.0))  # speed of a short leg's profile
    keep = s != 0
    c = step_across_edge(np.column_stack([xy, z])[keep], s[keep] > 0, a, b, max_rms_mm=0.15)
    assert (c.x_mm, c.y_mm) == pytest.approx((-200.0, 0.0))
    assert c.step_mm == pytest.approx(0.1, abs=1e-4)


def test_a_reading_off_another_surface_refuses_the_crossing() -> None:
    a, b = np.array([-300.0, 25.0]), np.array([-100.0, -20.0])
    xy = a + np.linspace(0, 1, 80)[:, None] * (b - a)
    s = surface_at(xy, GAP, MARGIN)
    z = np.where(s > 0, 0.1, 0.0)
    z[np.flatnonzero(s < 0)[3]] += 2.0  # a reflection off the seal
    keep = s != 0
    with pytest.raises(FlushError, match="the wall readings beside the crossing at .* scatter by"):
        step_across_edge(np.column_stack([xy, z])[keep], s[keep] > 0, a, b, max_rms_mm=0.15)


def test_each_crossing_counts_by_how_well_its_step_is_known() -> None:
    # the glass 0.2 mm recessed and flat against the wall; one crossing read from few noisy readings is off
    at = [(-250.0, 2.5), (-2.5, 250.0), (-2.5, 1200.0), (-1700.0, 2.5), (-900.0, 2.5)]
    crossings = [EdgeCrossing(x, y, 0.2, 0.002, 20, 20, 0.003, 0.003) for x, y in at]
    crossings[0] = EdgeCrossing(-250.0, 2.5, 0.26, 0.05, 5, 5, 0.04, 0.04)
    f = fit_flush_across_edges(crossings, max_rms_mm=0.15)
    assert f.dz_mm == pytest.approx(0.2, abs=0.001)  # unweighted: 0.2 + 0.03
    assert abs(f.drx_rad) < 1e-6 and abs(f.dry_rad) < 1e-6


def test_the_default_path_crosses_both_edges_near_and_far() -> None:
    middles = [tuple((a + b) / 2) for _, a, b in crossing_legs(CFG.sweep_path_mm, GAP, MARGIN)]
    assert middles == [(-250.0, 2.5), (-2.5, 250.0), (-2.5, 1200.0), (-1700.0, 2.5)]
    assert crossing_path_problem(CFG.sweep_path_mm, GAP, MARGIN) is None


@pytest.mark.parametrize(
    "path, problem",
    [
        ([(-60.0, -15.0), (-1700.0, -15.0), (-1700.0, 20.0), (-60.0, 20.0), (-20.0, 60.0), (-20.0, 1200.0),
          (15.0, 1200.0), (15.0, 60.0)], "crosses an edge on 2 legs"),  # glass and wall along separate legs
        ([(-350.0, -20.0), (-150.0, 25.0), (-700.0, 25.0), (-900.0, -20.0), (-1600.0, -20.0), (-1800.0, 25.0)],
         "span 1450 mm in x and 0 mm in y"),  # the top edge alone: dRx unknown
        ([(-350.0, -20.0), (-150.0, 45.0), (-25.0, 150.0), (20.0, 350.0), (20.0, 1100.0), (-25.0, 1300.0)],
         r"middles \[\[-250.0, 12.5\]\] lie outside the gap"),
        ([(-350.0, -10.0), (-150.0, 25.0), (-25.0, 150.0), (20.0, 350.0), (20.0, 1100.0), (-25.0, 1300.0)],
         "end less than 10 mm past the gap's margin"),
    ],
)  # fmt: skip
def test_a_path_that_cannot_give_the_flush_is_refused_where_the_cell_reads_on_the_move(path: list, problem: str) -> None:
    assert crossing_path_problem(path, GAP, MARGIN) is not None
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data["process"]["inspect"]["sweep_path_mm"] = [list(p) for p in path]
    parse_config(data)  # stop and go: the path is not used, nor checked
    data["process"]["align"]["mode"] = "on_the_fly"
    with pytest.raises(ConfigError, match=f"inspect.sweep_path_mm: .*{problem}"):
        parse_config(data)


def test_a_recipes_sweep_is_checked_as_its_cell_would_use_it() -> None:
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data["process"]["align"]["mode"] = "on_the_fly"
    parse_config(data)  # the door window's crossings beside its 150 mm arc
    door = next(r for r in data["process"]["recipes"] if r["name"] == "door-window")
    door["inspect"]["sweep_path_mm"] = door["inspect"]["sweep_path_mm"][:4]  # the top edge alone
    with pytest.raises(ConfigError, match=r"process.recipes\[1\] \(door-window\).*sweep_path_mm: it crosses an edge on 2 legs"):
        parse_config(data)
