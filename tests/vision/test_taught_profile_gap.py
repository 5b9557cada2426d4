"""The inspection's opening edge checked against the profile teaching recorded, against the twin's truth.

The inspection's gaps run from the opening's edge, which the recipe's rule picks as the corner
detector does. A dark paint line 1.5 mm outside the wall's edge (within the inspection's
``opening_search_px`` of the template) is counted by the rule and every gap is measured 1.5 mm
wide; with the taught profile the inspection is refused instead.
"""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.bench.inspection_vision import glass_at, taught_view
from cellctl.calibration.set_parts import TaughtProfileValues
from cellctl.calibration.taught_shot import taught_profile, taught_profile_of
from cellctl.config.sim import SimConfig
from cellctl.config.surface import BandConfig, SurfaceConfig
from cellctl.config.vision import FeatureConfig, VisionConfig
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.image_truth import camera_pose_seeing_corner, glass_truth
from cellctl.sim.world import nominal_world
from cellctl.vision import Lens
from cellctl.vision.feature import detect_feature
from cellctl.vision.gap import GapMeasurement, GapRefusal, in_plane_from_gaps, measure_gaps
from cellctl.vision.taught_profile import TaughtProfile

SIM = SimConfig()
LENS = Lens.from_intrinsics(SIM.camera.intrinsics)
CONFIG = VisionConfig()
GAP = SIM.glass.edge_gap_mm
D = 400.0
WORLD = nominal_world(SIM.world)
CORNER_PX = (LENS.cx, LENS.cy)
PAINT_LINE = SurfaceConfig(paint_band=BandConfig(width_mm=(1.5, 1.5), dn=(85.0, 85.0)))
INSTALL = np.array([0.3, -0.2, 0.4, 0.0, 0.0, 0.001])  # dX, dY, dZ mm; dRx, dRy, dRz rad


def _renderer(surface: SurfaceConfig) -> CameraRenderer:
    return CameraRenderer(SIM.camera.intrinsics, SIM.camera.render.model_copy(update={"surface": surface}))


def _pose(renderer: CameraRenderer) -> np.ndarray:
    return camera_pose_seeing_corner(renderer.camera, WORLD, CORNER_PX, distance_mm=D)


@pytest.fixture(scope="module")
def taught() -> TaughtProfile:
    """Teaching's template shot of the usual body at the shooting pose, recorded as teaching records it."""
    renderer = _renderer(SurfaceConfig())
    shot = detect_feature(renderer.render(_pose(renderer), WORLD, rng=np.random.default_rng(1)).image, LENS, CONFIG, None)
    assert shot.ok, shot.message
    profile = taught_profile_of(TaughtProfileValues.model_validate(taught_profile(shot.measurement, CONFIG.feature)))
    assert profile is not None
    return profile


def _inspect(
    surface: SurfaceConfig, seed: int, taught: TaughtProfile | None, feature: FeatureConfig | None = None
) -> tuple[GapMeasurement, dict[str, float]]:
    """The inspection of a known install on a body with ``surface`` (the recipe's ``feature`` settings, default
    the cell's), and its gaps' errors against the truth (mm)."""
    renderer = _renderer(surface)
    template, nine_point = taught_view(renderer, WORLD, CORNER_PX, D)
    pose, glass = _pose(renderer), glass_at(SIM, WORLD, INSTALL)
    image = renderer.render(pose, WORLD, rng=np.random.default_rng(seed), glass=glass).image
    m = measure_gaps(image, LENS, template, CONFIG.gap, gap_px_expected=GAP / nine_point.mm_per_px, taught=taught,
                     feature=feature or CONFIG.feature)  # fmt: skip
    if not m.ok:
        return m, {}
    truth = glass_truth(renderer.camera, pose, WORLD, glass, reference_along_mm=m.start_px * nine_point.mm_per_px)
    fig = in_plane_from_gaps(m, nine_point, nominal_gap_mm=GAP, dz_mm=truth.dz_mm, working_distance_mm=D,
                             principal_point_px=(LENS.cx, LENS.cy))  # fmt: skip
    return m, {"top": fig.top_gap_mm - truth.top_gap_mm, "right": fig.right_gap_mm - truth.right_gap_mm}


def test_a_paint_line_beside_the_opening_edge_is_refused_not_measured_into_the_gaps(taught: TaughtProfile) -> None:
    m, err = _inspect(PAINT_LINE, 2, None)  # the rule alone: both gaps 1.5 mm too wide, and accepted
    assert m.ok, m.message
    assert all(1.3 < e < 1.7 for e in err.values()), err
    m, _ = _inspect(PAINT_LINE, 2, taught)
    assert m.refusal is GapRefusal.OPENING_EDGE_NOT_FOUND
    assert "differs from the one taught" in m.message and "teach the recipe again" in m.message


def test_an_unchanged_body_is_inspected_as_without_the_check(taught: TaughtProfile) -> None:
    plain, err = _inspect(SurfaceConfig(), 3, None)
    checked, err_checked = _inspect(SurfaceConfig(), 3, taught)
    assert plain.ok and checked.ok, checked.message
    assert checked.steps_px == plain.steps_px and err_checked == err
    assert all(abs(e) < 0.05 for e in err.values()), err


def test_a_recipe_with_the_taught_check_switched_off_is_measured_by_its_rule_alone(taught: TaughtProfile) -> None:
    # [vision.feature] taught_profile = false: the recipe asks for its rule alone, even with a profile taught, so the
    # paint line is measured into both gaps (1.5 mm wider than the twin's) instead of refused
    off = CONFIG.feature.model_copy(update={"taught_profile": False})
    m, err = _inspect(PAINT_LINE, 2, taught, feature=off)
    assert m.ok, m.message
    assert all(1.3 < e < 1.7 for e in err.values()), err
