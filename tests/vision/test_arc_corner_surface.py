"""The arc detector on a real opening's corner: the recipe's arc among concentric ones (issue 21).

A real opening's corner shows a paint edge, the wall's edge, the flange's and the seal's borders
as arcs about one centre; the detector's seed circle may be any of them. Truth two ways: synthetic
images with the arcs at known offsets (vision_test_support), and the twin's own renders of a
150 mm corner with the surface it draws for each car body (paint band, flange, seal).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from arc_test_support import arc_centre, arc_point, occlude
from vision_test_support import SMALL_LENS, corner_image, ideal_grid

from cellctl.config import load_config
from cellctl.config.arc_vision import ArcCornerConfig, ArcSearchConfig
from cellctl.config.vision import FeatureConfig, RoiConfig
from cellctl.geometry.pose import apply_pose, invert_pose
from cellctl.geometry.rotation import rot_z
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.image_truth import camera_pose_seeing_corner
from cellctl.sim.world import sample_world
from cellctl.vision import Lens
from cellctl.vision.arc_corner import detect_arc_corner
from cellctl.vision.arc_profile import arc_profile
from cellctl.vision.quality import Refusal

R150 = 985.0  # 150 mm on the 1024 px SMALL_LENS
# From the wall inwards (px into the opening, grey beyond): paint edge, wall's edge, flange, seal.
# The flange border's arc is the strongest after the wall's, 60 px (6 %) inside it.
REAL_STEPS = ((-130.0, 138.0), (0.0, 60.0), (60.0, 36.0), (120.0, 20.0))
SEAL_INNER = FeatureConfig(count_from="opening", index=0, min_step_fraction=0.06)


def _config(**update: object) -> ArcCornerConfig:
    base = ArcCornerConfig(expected_radius_px=R150, roi=RoiConfig(width_px=1024, height_px=1024), search=ArcSearchConfig(downscale=2))
    return base.model_copy(update=update)


@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray]:
    return ideal_grid(SMALL_LENS)


@pytest.mark.parametrize(("corner", "angle"), [((1000.0, 20.0), 0.01), ((1060.0, 50.0), -0.015), ((980.0, 0.0), 0.0)])
def test_the_wall_edge_arc_among_concentric_arcs(grid, corner: tuple[float, float], angle: float) -> None:
    rng = np.random.default_rng(11)
    img = corner_image(SMALL_LENS, grid, corner, angle, radius_px=R150, steps=REAL_STEPS, noise_dn=2.0, blur_px=1.0, rng=rng)
    m = detect_arc_corner(img, SMALL_LENS, _config())
    assert m.ok, m.message
    # The flange's arc is 60 px inside, the paint edge 130 px outside: a wrong arc is far off.
    assert abs(m.radius_px - R150) < 0.3
    assert np.hypot(*(m.centre_px - arc_centre(corner, angle, R150))) < 0.3  # the p99 bar


def test_the_seal_arc_when_the_recipe_counts_from_the_opening(grid) -> None:
    corner, angle = (1000.0, 20.0), 0.01
    img = corner_image(SMALL_LENS, grid, corner, angle, radius_px=R150, steps=REAL_STEPS, noise_dn=0.5, blur_px=1.0,
                       rng=np.random.default_rng(12))  # fmt: skip
    limits = _config().limits.model_copy(update={"min_contrast_dn": 8.0, "radius_tolerance": 0.15})
    m = detect_arc_corner(img, SMALL_LENS, _config(feature=SEAL_INNER, limits=limits))
    assert m.ok, m.message
    assert abs(m.radius_px - (R150 - 120.0)) < 0.3  # concentric: the same centre, a smaller radius
    assert np.hypot(*(m.centre_px - arc_centre(corner, angle, R150))) < 0.3


def test_the_arcs_profile_is_the_median_of_the_recipes_cross_sections_spread_along_it(grid) -> None:
    """As across a straight edge: ``feature.cross_sections`` of the arc's normals, a dirt spot on one of them
    left out by the median, every concentric step at its drawn offset."""
    corner, angle = (1000.0, 20.0), 0.01
    img = corner_image(SMALL_LENS, grid, corner, angle, radius_px=R150, steps=REAL_STEPS, noise_dn=2.0, blur_px=1.0,
                       rng=np.random.default_rng(13))  # fmt: skip
    centre = arc_centre(corner, angle, R150)
    img = occlude(img, (*arc_point(centre, R150 - 30.0, 45.0), 40.0, 40.0), 250.0)  # a bright spot across the bands
    a = np.radians(np.linspace(15.0, 75.0, 4000))  # every quarter pixel along the arc, as the detector passes them
    normals = np.column_stack([np.cos(a), -np.sin(a)])
    profile = arc_profile(img, SMALL_LENS, centre, R150, normals, opening_darker=True, feature=FeatureConfig())
    assert profile.sections == FeatureConfig().cross_sections == 24
    found = [s.offset_px for s in profile.steps]
    assert len(found) == len(REAL_STEPS) and all(min(abs(f - o) for f in found) < 0.5 for o, _ in REAL_STEPS), found
    assert profile.feature_step is not None and abs(profile.feature_step.offset_px) < 0.5  # the wall's own edge


def test_a_rule_that_picks_no_arc_is_a_refusal(grid) -> None:
    img = corner_image(SMALL_LENS, grid, (1000.0, 20.0), 0.0, radius_px=R150, steps=REAL_STEPS)
    m = detect_arc_corner(img, SMALL_LENS, _config(feature=FeatureConfig(index=4)))
    assert not m.ok and m.refusal is Refusal.ARC_NOT_SEEN
    assert "arc.feature" in m.message


# The twin: a 1200 x 900 opening with 150 mm corners, its top tangent point at (450, 300) px
# before the body's placement error (up to 10 mm) and a turn of up to 1 deg.
TWIN_RADIUS_MM = 150.0


@pytest.fixture(scope="module")
def twin():
    sim = load_config("config/sim.toml").sim
    return sim, CameraRenderer(sim.camera.intrinsics, sim.camera.render), Lens.from_intrinsics(sim.camera.intrinsics)


def _project(T_B_C: np.ndarray, p_B: np.ndarray, K: np.ndarray) -> np.ndarray:
    q = apply_pose(invert_pose(T_B_C), p_B[None])[0]
    return np.array([K[0, 0] * q[0] / q[2] + K[0, 2], K[1, 1] * q[1] / q[2] + K[1, 2]])


@pytest.mark.parametrize("seed", range(6))
def test_the_twins_150_mm_corner_is_measured_on_the_wall_edge(twin, seed: int) -> None:
    sim, renderer, lens = twin
    rng = np.random.default_rng(100 + seed)
    world = dataclasses.replace(sample_world(sim.world, rng), width_mm=1200.0, height_mm=900.0, corner_radius_mm=TWIN_RADIUS_MM)
    assert len(renderer.surface_of(world).steps) >= 3  # paint edge, wall's edge, flange, seal: concentric arcs
    K = lens.camera_matrix
    R_px = TWIN_RADIUS_MM * K[0, 0] / 400.0
    shift = rng.uniform(-10.0, 10.0, 2) * K[0, 0] / 400.0
    T_B_C = camera_pose_seeing_corner(renderer.camera, world, (450.0 + R_px + shift[0], 300.0 + shift[1]), distance_mm=400.0,
                                      R_T_C=rot_z(np.radians(rng.uniform(-1.0, 1.0))))  # fmt: skip
    frame = renderer.render(T_B_C, world, rng=rng)
    m = detect_arc_corner(frame.image, lens, ArcCornerConfig(expected_radius_px=R_px))
    assert m.ok, m.message
    centre_B = apply_pose(world.T_B_T, np.array([[-TWIN_RADIUS_MM, TWIN_RADIUS_MM, 0.0]]))[0]
    true_centre = _project(T_B_C, centre_B, K)
    edge_B = apply_pose(world.T_B_T, np.array([[-TWIN_RADIUS_MM, 0.0, 0.0]]))[0]  # the top tangent point
    # The camera is square to the wall 400 mm away: the arc's radius is R fx / 400 in square px
    # (fx on both axes; fy is 0.02 % shorter, so in the ideal image the arc is 0.4 px flatter).
    # The flange's border is 4-7 mm (50-90 px) inside the wall's edge, the paint edge 8-15 mm
    # outside: a wrong arc is 50 px off or more.
    assert abs(m.radius_px - R_px) < 0.3
    assert np.hypot(*(m.centre_px - true_centre)) < 0.3  # the p99 bar
    assert m.orientation is not None and m.orientation.theta_rad is not None, m.orientation
    true_top = _project(T_B_C, apply_pose(world.T_B_T, np.array([[-TWIN_RADIUS_MM - 100.0, 0.0, 0.0]]))[0], K)
    d = _project(T_B_C, edge_B, K) - true_top
    assert abs(np.degrees(m.orientation.theta_rad - np.arctan2(d[1], d[0]))) < 0.02


def test_the_arc_shot_is_drawn_for_the_record(twin) -> None:
    import cv2

    from cellctl.vision.annotate_arc import annotate_arc

    sim, renderer, lens = twin
    rng = np.random.default_rng(7)
    world = dataclasses.replace(sample_world(sim.world, rng), width_mm=1200.0, height_mm=900.0, corner_radius_mm=TWIN_RADIUS_MM)
    R_px = TWIN_RADIUS_MM * lens.fx / 400.0
    T_B_C = camera_pose_seeing_corner(renderer.camera, world, (450.0 + R_px, 300.0), distance_mm=400.0)
    image = renderer.render(T_B_C, world, rng=rng).image
    m = detect_arc_corner(image, lens, ArcCornerConfig(expected_radius_px=R_px))
    refused = detect_arc_corner(image, lens, ArcCornerConfig(expected_radius_px=0.7 * R_px))
    for shot in (m, refused):
        png = annotate_arc(image, shot, lens, RoiConfig(), width_px=512)
        picture = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        assert picture.shape == (512, 512, 3)
    assert m.ok and not refused.ok


def test_an_arc_without_its_straight_edge_aims_a_first_shot_but_is_refused_after(grid) -> None:
    from cellctl.config.vision import VisionConfig
    from cellctl.vision.feature import detect_feature

    # The whole arc in view and no straight edge beyond it (as a body placed far off makes the first shot).
    img = corner_image(SMALL_LENS, grid, (1000.0, 20.0), 0.01, radius_px=R150, noise_dn=1.0, rng=np.random.default_rng(15))
    verify = detect_feature(img, SMALL_LENS, VisionConfig(), _config())
    assert not verify.ok and verify.features is None and "second feature" in verify.message
    first = detect_feature(img, SMALL_LENS, VisionConfig(), _config(), need_orientation=False)
    assert first.ok and first.kind == "arc" and first.features is not None
    assert np.hypot(first.features.u_px - arc_centre((1000.0, 20.0), 0.01, R150)[0],
                    first.features.v_px - arc_centre((1000.0, 20.0), 0.01, R150)[1]) < 0.1  # fmt: skip
    assert np.isnan(first.features.theta_rad) and np.isnan(first.features.top_angle_rad)  # it turns nothing
