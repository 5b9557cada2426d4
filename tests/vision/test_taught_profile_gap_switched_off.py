"""A recipe that switches the taught-profile check off (``[vision.feature] taught_profile = false``) is inspected by
its rule alone, even with a taught profile recorded (a rule a mutation run found unguarded).

Truth: the twin's body with a dark paint line 1.5 mm outside the wall's edge (the rule counts it: both gaps come
out 1.5 mm wide against the twin's truth), and the profile taught on the usual body, as in
tests/vision/test_taught_profile_gap.py.
"""

from __future__ import annotations

import numpy as np

from cellctl.bench.inspection_vision import glass_at, taught_view
from cellctl.calibration.set_parts import TaughtProfileValues
from cellctl.calibration.taught_shot import taught_profile, taught_profile_of
from cellctl.config.sim import SimConfig
from cellctl.config.surface import BandConfig, SurfaceConfig
from cellctl.config.vision import VisionConfig
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.image_truth import camera_pose_seeing_corner, glass_truth
from cellctl.sim.world import nominal_world
from cellctl.vision import Lens
from cellctl.vision.feature import detect_feature
from cellctl.vision.gap import GapRefusal, in_plane_from_gaps, measure_gaps

SIM = SimConfig()
LENS = Lens.from_intrinsics(SIM.camera.intrinsics)
CONFIG = VisionConfig()
GAP = SIM.glass.edge_gap_mm
D = 400.0
WORLD = nominal_world(SIM.world)
CORNER_PX = (LENS.cx, LENS.cy)
PAINT_LINE = SurfaceConfig(paint_band=BandConfig(width_mm=(1.5, 1.5), dn=(85.0, 85.0)))


def _renderer(surface: SurfaceConfig) -> CameraRenderer:
    return CameraRenderer(SIM.camera.intrinsics, SIM.camera.render.model_copy(update={"surface": surface}))


def test_a_recipe_with_the_taught_check_switched_off_is_measured_by_its_rule_alone() -> None:
    usual = _renderer(SurfaceConfig())
    pose = camera_pose_seeing_corner(usual.camera, WORLD, CORNER_PX, distance_mm=D)
    shot = detect_feature(usual.render(pose, WORLD, rng=np.random.default_rng(1)).image, LENS, CONFIG, None)
    assert shot.ok, shot.message
    taught = taught_profile_of(TaughtProfileValues.model_validate(taught_profile(shot.measurement, CONFIG.feature)))
    assert taught is not None

    painted = _renderer(PAINT_LINE)
    template, nine_point = taught_view(painted, WORLD, CORNER_PX, D)
    glass = glass_at(SIM, WORLD, np.array([0.3, -0.2, 0.4, 0.0, 0.0, 0.001]))
    image = painted.render(pose, WORLD, rng=np.random.default_rng(2), glass=glass).image
    gap_px = GAP / nine_point.mm_per_px
    checked = measure_gaps(image, LENS, template, CONFIG.gap, gap_px_expected=gap_px, taught=taught)
    assert checked.refusal is GapRefusal.OPENING_EDGE_NOT_FOUND, checked.message  # the check on: refused
    off = CONFIG.feature.model_copy(update={"taught_profile": False})
    m = measure_gaps(image, LENS, template, CONFIG.gap, gap_px_expected=gap_px, feature=off, taught=taught)
    assert m.ok, m.message
    truth = glass_truth(painted.camera, pose, WORLD, glass, reference_along_mm=m.start_px * nine_point.mm_per_px)
    fig = in_plane_from_gaps(m, nine_point, nominal_gap_mm=GAP, dz_mm=truth.dz_mm, working_distance_mm=D,
                             principal_point_px=(LENS.cx, LENS.cy))  # fmt: skip
    # the rule's edge is the paint line's: both gaps 1.5 mm wider than the twin's, as the recipe asked
    assert 1.3 < fig.top_gap_mm - truth.top_gap_mm < 1.7 and 1.3 < fig.right_gap_mm - truth.right_gap_mm < 1.7
