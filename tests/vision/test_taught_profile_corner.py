"""The corner's feature edge found again by the profile teaching recorded, against the twin's truth.

Teaching: the twin's car body at its nominal place with its usual surface (a faint primer band on
the wall, the wall's edge, a flange and a seal), the camera at the shooting pose. The cycle's body
shows a dark paint line 2.8 mm outside the wall's edge (the twin's paint band drawn narrow and
dark): the recipe's rule (the first strong falling step from the wall) counts it, and the corner
is measured on it, several mm off and with a tiny sigma. With the taught profile the shot is refused.
"""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.calibration.set_parts import TaughtProfileValues
from cellctl.calibration.taught_shot import taught_profile, taught_profile_of
from cellctl.config.feature import CornerRadius
from cellctl.config.sim import SimConfig, WorldConfig
from cellctl.config.surface import BandConfig, SurfaceConfig
from cellctl.config.vision import FeatureConfig, VisionConfig
from cellctl.geometry.rotation import rot_z
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.image_truth import camera_pose_seeing_corner, corner_truth
from cellctl.sim.world import World, nominal_world, sample_world
from cellctl.vision import Lens, Refusal
from cellctl.vision.feature import FeatureShot, detect_feature
from cellctl.vision.taught_profile import TaughtProfile

SIM = SimConfig()
LENS = Lens.from_intrinsics(SIM.camera.intrinsics)
CONFIG = VisionConfig()
MM_PER_PX = 400.0 / SIM.camera.intrinsics.fx  # at the shooting distance
RADIUS = CornerRadius(30.0 / MM_PER_PX, "the twin's 30 mm corner")  # the recipe's radius, as the cycle passes it
TEMPLATE_PX = (980.0, 1050.0)
PAINT_LINE = SurfaceConfig(paint_band=BandConfig(width_mm=(2.8, 2.8), dn=(85.0, 85.0)))


def _shot(surface: SurfaceConfig, world: World, seed: int, taught: TaughtProfile | None, config: VisionConfig = CONFIG
          ) -> tuple[FeatureShot, float]:  # fmt: skip
    """The cycle's detector on a twin frame at the shooting pose, and its corner's distance from the truth (mm)."""
    renderer = CameraRenderer(SIM.camera.intrinsics, SIM.camera.render.model_copy(update={"surface": surface}))
    pose = camera_pose_seeing_corner(renderer.camera, world, TEMPLATE_PX, R_T_C=rot_z(np.radians(0.6)))
    image = renderer.render(pose, world, rng=np.random.default_rng(seed)).image
    shot = detect_feature(image, LENS, config, None, corner_radius=RADIUS, taught=taught)
    truth = corner_truth(renderer.camera, pose, world).corner_undistorted_px
    m = shot.measurement
    off = float("nan") if m.corner_px is None else float(np.linalg.norm(m.corner_px - truth)) * MM_PER_PX  # type: ignore[union-attr]
    return shot, off


@pytest.fixture(scope="module")
def taught() -> TaughtProfile:
    """Teaching's record of the template's profiles, through the teaching part's JSON and back."""
    shot, off = _shot(SurfaceConfig(), nominal_world(SIM.world), 5, None)
    assert shot.ok and off < 0.02, shot.message
    record = taught_profile(shot.measurement, CONFIG.feature)
    assert record is not None and set(record["edges"]) == {"top", "right"}  # type: ignore[arg-type]
    profile = taught_profile_of(TaughtProfileValues.model_validate_json(TaughtProfileValues.model_validate(record).model_dump_json()))
    assert profile is not None
    return profile


def test_a_paint_line_beside_the_wall_edge_is_refused_not_measured_off(taught: TaughtProfile) -> None:
    world = nominal_world(SIM.world)
    # The rule alone (a set taught before profiles were recorded): the paint line is counted and
    # the corner passes every check 2.8 mm off on both edges (4 mm in the plane), with a tiny sigma.
    shot, off = _shot(PAINT_LINE, world, 6, None)
    assert shot.ok, shot.message
    assert 3.0 < off < 5.0 and shot.sigma_px is not None and shot.sigma_px < CONFIG.limits.max_corner_sigma_px
    # With the taught profile: the step the rule would take has a step 37 px inside it that teaching
    # did not see, and the wall's edge is too faint now to be the taught feature: refused, naming it.
    shot, _ = _shot(PAINT_LINE, world, 6, taught)
    assert not shot.ok and shot.features is None
    assert shot.refusal is Refusal.FEATURE_NOT_FOUND
    assert "differs from the one taught" in shot.message and "that teaching did not see" in shot.message
    assert "teach the recipe again" in shot.message and "[vision.feature]" in shot.message


@pytest.mark.parametrize("body", [0, 1, 2])
def test_an_unchanged_body_gives_the_same_corner_as_without_the_check(taught: TaughtProfile, body: int) -> None:
    # Another car body of the recipe at another placement: its primer band, flange and seal are
    # drawn anew within the twin's ranges (widths vary by mm), which the check leaves alone.
    world = sample_world(WorldConfig(), np.random.default_rng(40 + body))
    plain, off = _shot(SurfaceConfig(), world, body, None)
    checked, off_checked = _shot(SurfaceConfig(), world, body, taught)
    assert plain.ok and checked.ok, checked.message
    assert checked.features == plain.features and off_checked == off < 0.02


def test_a_rule_changed_since_teaching_is_refused(taught: TaughtProfile) -> None:
    seal = CONFIG.model_copy(update={"feature": FeatureConfig(count_from="opening", min_step_fraction=0.06)})
    shot, _ = _shot(SurfaceConfig(), nominal_world(SIM.world), 7, taught, seal)
    assert shot.refusal is Refusal.FEATURE_NOT_FOUND and "changed since teaching" in shot.message
    # Switched off ([vision.feature] taught_profile = false), the rule alone counts, as without a record.
    off = seal.model_copy(update={"feature": seal.feature.model_copy(update={"taught_profile": False})})
    shot, _ = _shot(SurfaceConfig(), nominal_world(SIM.world), 7, taught, off)
    alone, _ = _shot(SurfaceConfig(), nominal_world(SIM.world), 7, None, off)
    assert (shot.refusal, shot.message, shot.features) == (alone.refusal, alone.message, alone.features)
