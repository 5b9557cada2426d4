"""The corner detector's "no top edge ... segments lean" refusal says when the leaning segments are the opening's rounded
corner (its arc filling the view, the straight edge out of it), naming the corner radius; a turned car body's straight
edges are still blamed on its posture.

Truth: the twin's renders of a car body with a known corner radius, the camera turned about its axis by a known angle
(the turned straight edges) or the corner placed far off the image's centre (a 45 mm arc fills the view).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from cellctl.bench.vision import one_core_camera
from cellctl.config.vision import VisionConfig
from cellctl.geometry.rotation import rot_z
from cellctl.sim.image_truth import camera_pose_seeing_corner
from cellctl.sim.world import nominal_world
from cellctl.vision import detect_corner

SIM, LENS, RENDERER = one_core_camera()


def _message(radius_mm: float, corner_px: tuple[float, float], roll_deg: float) -> str:
    world = nominal_world(SIM.world.model_copy(update={"corner_radius_mm": radius_mm}))
    pose = camera_pose_seeing_corner(RENDERER.camera, world, corner_px, R_T_C=rot_z(np.radians(roll_deg)))
    m = detect_corner(RENDERER.render(pose, world, rng=np.random.default_rng(1)).image, LENS, VisionConfig())
    assert not m.ok
    return m.message


@pytest.mark.parametrize("corner_px", [(600.0, 1000.0), (600.0, 1300.0)])
def test_a_45_mm_arc_filling_the_view_is_named_as_the_corner_radius(corner_px: tuple[float, float]) -> None:
    text = _message(45.0, corner_px, 0.0)
    assert text.startswith("no top edge found") and "past vision.coarse.max_tilt_deg (12 deg)" in text, text
    assert "the opening's rounded corner" in text and "layout.opening.corner_radius_mm" in text, text
    found = re.search(r"arcs about one centre \(radius (\d+)-(\d+) px\)", text)
    assert found is not None, text
    wall_px = 45.0 * SIM.camera.intrinsics.fx / 400.0  # the wall's edge: the outermost of the concentric arcs drawn
    assert abs(float(found.group(2)) / wall_px - 1.0) < 0.05, (found.groups(), wall_px)


@pytest.mark.parametrize(("radius_mm", "roll_deg"), [(30.0, 20.0), (30.0, -25.0), (10.0, 20.0), (5.0, 35.0)])
def test_a_turned_car_bodys_straight_edges_are_still_its_posture(radius_mm: float, roll_deg: float) -> None:
    text = _message(radius_mm, (1024.0, 1024.0), roll_deg)
    assert "edge found" in text and "check the car body's posture or raise the limit" in text, text
    assert "corner_radius_mm" not in text and "arcs about" not in text, text
