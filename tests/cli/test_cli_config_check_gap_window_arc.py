"""`cellctl config check` refuses a corner-method opening whose `[vision.gap]` window starts on the corner's arc, naming
vision.gap.start_px, the corner radius and the fix; the twin is the truth that the refused window fails and the fixed one
measures.

By hand, both shipped files: the lens fx = 5250 px at 400 mm, 0.07619 mm/px; vision.gap.start_px = 440 px is 33.5 mm
along each edge from the corner. The window must start 1 mm past the arc (feature.GAP_PAST_ARC_MM): a radius up to
440 x 0.07619 - 1 = 32.52 mm passes. For 45 mm: the first start is 46 / 0.07619 = 603.75, so 604 px. A glass within
process.tolerance (1 deg, 0.5 mm) then shows its edge (603.75 + 560 / 2) x tan(1 deg) + 0.5 / 0.07619 = 15.43 + 6.56
= 22.0 px from the nominal gap at the window's middle: glass_search_px at least 23. The window keeps its 150 px in the
image up to a start of 756 px with the corner at the image's centre (tests/cli/test_cli_config_check_geometry.py); a
45 mm corner's default aim moves it 482 px up and right (feature.corner_shift_px, README "Large corner radii"), so up
to 756 + 482 = 1238 px.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from config_check_support import check as _check
from config_check_support import refused as _refused
from config_check_support import shipped_copy as _copy

from cellctl.bench.inspection_vision import WORKING_DISTANCE_MM, glass_at, taught_view
from cellctl.bench.vision import one_core_camera
from cellctl.config.vision import GapVisionConfig
from cellctl.sim.image_truth import camera_pose_seeing_corner, glass_truth
from cellctl.sim.world import sample_world
from cellctl.vision.gap import in_plane_from_gaps, measure_gaps

RADIUS_LINE = "corner_radius_mm = 30.0"  # [layout.opening]'s, once in each file


@pytest.mark.parametrize("which", ["sim", "hardware"])
def test_a_window_starting_on_a_45_mm_corners_arc_is_refused_with_the_fix(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], which: str
) -> None:
    text = _refused(capsys, _copy(tmp_path, which, ((RADIUS_LINE, "corner_radius_mm = 45.0"),)))
    assert ("vision.gap.start_px = 440 (33.5 mm at layout.camera's 0.07619 mm/px) starts the inspection's window along "
            "each edge on the corner's arc: layout.opening.corner_radius_mm = 45") in text  # fmt: skip
    assert "raise vision.gap.start_px" in text and "to at least 604 and vision.gap.glass_search_px to at least 23" in text
    assert "a start up to 1238 px keeps the window in the image" in text and "recipes[" not in text


def test_the_largest_radius_the_default_window_passes_is_the_one_worked_by_hand(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc, err = _check(capsys, _copy(tmp_path, "sim", ((RADIUS_LINE, "corner_radius_mm = 32.5"),)))
    assert rc == 0, err
    text = _refused(capsys, _copy(tmp_path, "sim", ((RADIUS_LINE, "corner_radius_mm = 32.6"),)))
    assert "layout.opening.corner_radius_mm = 32.6" in text and "to at least 441" in text


def test_the_window_the_refusal_asks_for_passes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    edits = ((RADIUS_LINE, "corner_radius_mm = 45.0"), ("start_px = 440.0 ", "start_px = 604.0 "),
             ("glass_search_px = 20.0 ", "glass_search_px = 23.0 "))  # fmt: skip
    rc, err = _check(capsys, _copy(tmp_path, "sim", edits))
    assert rc == 0, err


def test_a_recipes_own_radius_is_refused_by_the_recipes_name(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    recipe = 'description = "2000 x 1500 mm side-window glass"'
    text = _refused(capsys, _copy(tmp_path, "sim", ((recipe, recipe + "\n[process.recipes.opening]\ncorner_radius_mm = 45.0"),)))
    assert "process.recipes[0] (side-window): vision.gap.start_px = 440 (33.5 mm" in text
    assert "corner_radius_mm = 45" in text and "to at least 604" in text


def test_the_twin_loses_tolerance_edge_glasses_on_the_refused_window_and_measures_them_on_the_asked_for_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The 45 mm corner's inspection on the twin, with glasses at the tolerance's edge (0.45 mm, 1 deg): the default
    window (refused) refuses or mis-measures some; the one the refusal asks for measures each within 0.02 mm."""
    text = _refused(capsys, _copy(tmp_path, "sim", ((RADIUS_LINE, "corner_radius_mm = 45.0"),)))
    start, search = (float(v) for v in re.search(r"start_px \(.*?\) to at least (\d+) and vision\.gap\.glass_search_px "
                                                 r"to at least (\d+)", text).groups())  # type: ignore[union-attr]
    sim, lens, renderer = one_core_camera()
    sim = sim.model_copy(update={"world": sim.world.model_copy(update={"corner_radius_mm": 45.0})})
    gap = sim.glass.edge_gap_mm
    deviations = ([0.45, -0.45, 0.0, 0.0, 0.0, 1.0], [-0.45, 0.45, 0.3, 0.5, -0.5, -1.0], [0.45, 0.45, 0.0, 0.0, 0.0, -1.0],
                  [-0.45, -0.45, 0.0, 0.0, 0.0, 1.0])  # fmt: skip

    def errors(cfg: GapVisionConfig) -> list[float | str]:
        out: list[float | str] = []
        for dev in deviations:
            rng = np.random.default_rng(1)
            world = sample_world(sim.world, rng)
            glass = glass_at(sim, world, np.array(dev[:3] + [np.radians(v) for v in dev[3:]]))
            corner = (renderer.camera.cx, renderer.camera.cy)
            template, nine = taught_view(renderer, world, corner, WORKING_DISTANCE_MM)
            pose = camera_pose_seeing_corner(renderer.camera, world, corner, distance_mm=WORKING_DISTANCE_MM)
            m = measure_gaps(renderer.render(pose, world, rng=rng, glass=glass).image, lens, template, cfg,
                             gap_px_expected=gap / nine.mm_per_px)  # fmt: skip
            if not m.ok:
                out.append(m.message)
                continue
            dz = float(dev[2])
            f = in_plane_from_gaps(m, nine, nominal_gap_mm=gap, dz_mm=dz, working_distance_mm=WORKING_DISTANCE_MM,
                                   principal_point_px=(lens.cx, lens.cy))  # fmt: skip
            t = glass_truth(renderer.camera, pose, world, glass, reference_along_mm=f.reference_along_mm)
            out.append(max(abs(f.dx_mm - t.dx_mm), abs(f.dy_mm - t.dy_mm), abs(f.top_gap_mm - t.top_gap_mm)))
        return out

    asked = errors(GapVisionConfig(start_px=start, glass_search_px=search))
    assert all(isinstance(e, float) and e < 0.02 for e in asked), asked
    default = errors(GapVisionConfig())
    assert any(isinstance(e, str) or e > 0.02 for e in default), default
