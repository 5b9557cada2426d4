"""The twin's car-body surface (paint band, flange, seal, marks, dirt) against its known truth."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError
from shared_support import edge_crossing

from cellctl.config.mounting import CameraIntrinsics
from cellctl.config.render import DisturbanceConfig, OcclusionConfig, RenderConfig
from cellctl.config.sim import WorldConfig
from cellctl.config.surface import (
    CLEAN_SURFACE,
    BandConfig,
    DirtConfig,
    MarksConfig,
    SurfaceConfig,
)
from cellctl.geometry.pose import apply_pose
from cellctl.geometry.rotation import rot_x, rot_y, rot_z
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.camera_blocks import PlaneView
from cellctl.sim.edge_coverage import coverage_from_sdf, rounded_rect_sdf
from cellctl.sim.image_truth import (
    camera_pose_seeing_corner,
    corner_truth,
    edge_curve_px,
)
from cellctl.sim.surface import DrawnSurface, draw_surface
from cellctl.sim.world import World, nominal_world, sample_world

INTR = CameraIntrinsics()
CROP = CameraIntrinsics(width_px=500, height_px=436, cx=INTR.cx - 760.0, cy=INTR.cy - 800.0)
FLAT = {"vignetting_power": 0.0, "lighting_gradient": 0.0}  # illumination exactly 1
ALL_ON = SurfaceConfig(
    marks=MarksConfig(count=(3, 3), within_mm=20.0, width_mm=(0.5, 1.5)),
    dirt=DirtConfig(count=(25, 25), within_mm=25.0, spread_mm=10.0),
)


def _project(renderer: CameraRenderer, T_B_C: np.ndarray, world: World, xy_T: tuple[float, float]) -> np.ndarray:
    return renderer.project(apply_pose(world.T_B_T, np.array([[xy_T[0], xy_T[1], 0.0]])), T_B_C)[0]


def _crossing(profile: np.ndarray, centre: float, half: int = 7) -> float:
    return edge_crossing(profile, centre, half)


@pytest.fixture(scope="module")
def world() -> World:
    return sample_world(WorldConfig(), np.random.default_rng(7))


# --- the profile across the edge ------------------------------------------------------------------


@pytest.mark.parametrize("contrast", [1.0, 0.5])
def test_plateau_levels_are_the_drawn_levels(world: World, contrast: float) -> None:
    config = RenderConfig(**FLAT, disturbances=DisturbanceConfig(contrast_factor=contrast))
    renderer = CameraRenderer(INTR, config)
    T_B_C = camera_pose_seeing_corner(renderer.camera, world, (1300.0, 700.0), R_T_C=rot_z(0.05) @ rot_x(0.02))
    signal, applied = renderer.render_signal(T_B_C, world)
    drawn = draw_surface(config.surface, world.surface_seed, world)
    assert applied.surface is not None and len(applied.surface.steps) == 4
    mean = 0.5 * (config.wall_dn + config.opening_dn)
    expected = [mean + contrast * (level - mean) for level in drawn.levels]
    assert applied.surface.levels == pytest.approx(expected, abs=1e-12)
    assert (applied.wall_dn, applied.opening_dn) == pytest.approx((expected[0], expected[-1]), abs=1e-12)
    # Mid-plateau on both straight edges (plateaus >= 4 mm wide, blur reach < 0.5 mm).
    bounds = [drawn.steps[0][0] + 5.0, *(o for o, _ in drawn.steps), drawn.steps[-1][0] - 5.0]
    for k, level in enumerate(expected):
        sd = 0.5 * (bounds[k] + bounds[k + 1])
        for xy in ((-60.0, -sd), (sd, 60.0)):  # top edge (y = -sd), right edge (x = sd)
            u, v = np.rint(_project(renderer, T_B_C, world, xy)).astype(int)
            assert signal[v, u] == pytest.approx(level, abs=1e-4), f"plateau {k} at {xy}"


@pytest.mark.parametrize("tilt", [(0.0, 0.0, 0.0), (0.04, -0.05, 0.12)])
def test_steps_lie_on_the_projected_offset_edges(world: World, tilt: tuple[float, float, float]) -> None:
    renderer = CameraRenderer(INTR, RenderConfig(**FLAT))
    R = rot_x(tilt[0]) @ rot_y(tilt[1]) @ rot_z(tilt[2])
    T_B_C = camera_pose_seeing_corner(renderer.camera, world, (1700.0, 350.0), distance_mm=400.0, R_T_C=R)
    signal, applied = renderer.render_signal(T_B_C, world)
    assert applied.surface is not None
    errors = []
    for offset, _ in applied.surface.steps:
        for edge in ("top", "right"):
            a = np.linspace(45.0, 120.0, 200001)
            curve = edge_curve_px(renderer.camera, T_B_C, world, edge, a, inset_mm=-offset)
            across, along = (1, 0) if edge == "top" else (0, 1)
            order = np.argsort(curve[:, along])
            c_along, c_across = curve[order, along], curve[order, across]
            lo, hi = max(int(np.ceil(c_along[0])), 20), min(int(c_along[-1]), 2027)
            for line in range(lo, hi, 37):
                true_pos = float(np.interp(line, c_along, c_across))
                if not 20 < true_pos < 2027:
                    continue
                profile = signal[:, line] if edge == "top" else signal[line, :]
                errors.append(_crossing(profile, true_pos) - true_pos)
    errors_px = np.abs(errors)
    assert len(errors_px) > 80
    assert errors_px.max() < 0.05, f"worst step {errors_px.max():.3f} px from its projected edge"


def test_corner_truth_of_an_inset_edge(world: World) -> None:
    camera = CameraRenderer(CROP, RenderConfig()).camera
    T_B_C = camera_pose_seeing_corner(camera, world, (300.0, 200.0), R_T_C=rot_z(0.1) @ rot_x(0.04))
    base = corner_truth(camera, T_B_C, world)
    zero = corner_truth(camera, T_B_C, world, inset_mm=0.0)
    for name, value in vars(base).items():
        assert np.array_equal(value, getattr(zero, name)), name
    for inset in (15.6, -10.4):
        truth = corner_truth(camera, T_B_C, world, inset)
        expected = camera.project(apply_pose(world.T_B_T, np.array([[-inset, inset, 0.0]])), T_B_C)[0]
        assert np.linalg.norm(truth.corner_px - expected) < 1e-9
        # The edges keep their direction in T; in the image they turn a little under perspective.
        far = camera.project(apply_pose(world.T_B_T, np.array([[-inset - 30.0, inset, 0.0]])), T_B_C)[0]
        top = (far - truth.corner_px) / np.linalg.norm(far - truth.corner_px)
        assert top @ truth.top_edge_tangent_px > 0.9999
        assert abs(truth.edge_angle_rad - base.edge_angle_rad) < 1e-2


# --- marks and dirt -------------------------------------------------------------------------------


def test_marks_and_dirt_appear_where_drawn(world: World) -> None:
    surface = SurfaceConfig(
        marks=MarksConfig(count=(3, 3), within_mm=40.0, width_mm=(1.3, 1.5), kind="either"),
        dirt=DirtConfig(count=(12, 12), within_mm=40.0, spread_mm=15.0, radius_mm=(0.7, 0.8)),
    )
    renderer = CameraRenderer(INTR, RenderConfig(**FLAT, surface=surface))
    T_B_C = camera_pose_seeing_corner(renderer.camera, world, (1400.0, 700.0), R_T_C=rot_z(0.05))
    signal, applied = renderer.render_signal(T_B_C, world)
    drawn = applied.surface
    assert drawn is not None and drawn.overlays == draw_surface(surface, world.surface_seed, world).overlays
    assert len(drawn.marks) == 3 and len(drawn.dirt) == 12
    checked = 0
    for k, feature in enumerate(drawn.overlays):
        later = drawn.overlays[k + 1 :]
        x, y = np.array([feature.centre_mm[0]]), np.array([feature.centre_mm[1]])
        if any(f.sdf(x, y)[0][0] < 1.0 for f in later):
            continue  # covered (or nearly) by a later overlay
        u, v = np.rint(_project(renderer, T_B_C, world, feature.centre_mm)).astype(int)
        assert signal[v, u] == pytest.approx(feature.level_dn, abs=1e-4), f"overlay {k} at {feature.centre_mm}"
        checked += 1
    assert checked >= 8


# --- one surface per car body ---------------------------------------------------------------------


def test_one_surface_per_car_body_across_frames_and_poses() -> None:
    config = RenderConfig(surface=ALL_ON)
    renderer = CameraRenderer(CROP, config)
    bodies = [sample_world(WorldConfig(), np.random.default_rng(s)) for s in (1, 2)]
    seen = []
    for world in bodies:
        frames = []
        for corner, rz in (((300.0, 200.0), 0.0), ((250.0, 150.0), 0.1)):
            T_B_C = camera_pose_seeing_corner(renderer.camera, world, corner, R_T_C=rot_z(rz))
            frames.append(renderer.render(T_B_C, world, rng=np.random.default_rng(len(frames))).applied.surface)
        assert frames[0] == frames[1] and frames[0] is not None
        seen.append(frames[0])
    assert seen[0].steps != seen[1].steps and seen[0].dirt != seen[1].dirt
    # The seed follows the placement, and a fresh renderer draws the same surface.
    again = sample_world(WorldConfig(), np.random.default_rng(1))
    assert again.surface_seed == bodies[0].surface_seed
    assert CameraRenderer(CROP, config).surface_of(again) == seen[0]


def test_sample_world_draws_nothing_extra_from_the_rng() -> None:
    a, b = np.random.default_rng(5), np.random.default_rng(5)
    sample_world(WorldConfig(), a)
    b.uniform(-1.0, 1.0, 3)
    b.uniform(-1.0, 1.0, 3)
    assert a.random() == b.random()
    assert nominal_world(WorldConfig()).surface_seed == nominal_world(WorldConfig()).surface_seed
    assert World(np.eye(4), 100.0, 80.0, 5.0).surface_seed == 0  # old constructors still work


def test_draws_stay_within_the_configured_ranges() -> None:
    config = ALL_ON.model_copy(update={"marks": MarksConfig(count=(0, 4), within_mm=30.0)})
    world = nominal_world(WorldConfig())
    counts = set()
    for seed in range(300):
        s = draw_surface(config, seed, world)
        offsets = [o for o, _ in s.steps]
        paint, flange, seal = offsets[0], -offsets[2], offsets[2] - offsets[3]
        assert offsets[1] == 0.0 and s.steps[-1][1] == RenderConfig().opening_dn
        for value, band in ((paint, config.paint_band), (flange, config.flange), (seal, config.seal)):
            assert band is not None and band.width_mm[0] - 1e-12 <= value <= band.width_mm[1] + 1e-12
        for (_, level), band in zip(s.steps[:3], (config.paint_band, config.flange, config.seal), strict=True):
            assert band is not None and band.dn[0] <= level <= band.dn[1]
        mc, dc = config.marks, config.dirt
        assert mc is not None and dc is not None
        counts.add(len(s.marks))
        assert mc.count[0] <= len(s.marks) <= mc.count[1] and dc.count[0] <= len(s.dirt) <= dc.count[1]
        for m in s.marks:
            assert 0.0 <= m.along_mm <= mc.within_mm
            on_line = (m.centre_mm[1] == 0.0) if m.edge == "top" else (m.centre_mm[0] == 0.0)
            assert on_line
            to_edge = np.degrees(m.angle_rad) - (0.0 if m.edge == "top" else 90.0)
            assert mc.angle_deg[0] - 1e-9 <= to_edge <= mc.angle_deg[1] + 1e-9
            assert mc.length_mm[0] <= m.length_mm <= mc.length_mm[1] and mc.width_mm[0] <= m.width_mm <= mc.width_mm[1]
            assert mc.bright_dn[0] <= m.level_dn <= mc.bright_dn[1] or mc.dark_dn[0] <= m.level_dn <= mc.dark_dn[1]
        for d in s.dirt:
            x, y = d.centre_mm
            on_top = -dc.within_mm <= x <= 0.0 and abs(y) <= dc.spread_mm
            on_right = 0.0 <= y <= dc.within_mm and abs(x) <= dc.spread_mm
            assert on_top or on_right
            assert dc.radius_mm[0] <= d.radius_mm <= dc.radius_mm[1] and dc.dn[0] <= d.level_dn <= dc.dn[1]
    assert counts == {0, 1, 2, 3, 4}
    # Fixed ranges give fixed values; switching parts off leaves the others' draws alone.
    fixed = SurfaceConfig(paint_band=None, flange=BandConfig(width_mm=(5.0, 5.0), dn=(70.0, 70.0)), seal=None)
    assert draw_surface(fixed, 3, world).steps == ((0.0, 70.0), (-5.0, 20.0))
    assert draw_surface(CLEAN_SURFACE, 3, world).steps == ((0.0, 20.0),)
    with_dirt = draw_surface(ALL_ON, 11, world)
    assert draw_surface(CLEAN_SURFACE.model_copy(update={"dirt": ALL_ON.dirt}), 11, world).dirt == with_dirt.dirt


def test_bad_surface_config_names_the_field() -> None:
    with pytest.raises(ValidationError, match=r"(?s)flange\.width_mm.*swap"):
        SurfaceConfig(flange={"width_mm": (7.0, 4.0), "dn": (60.0, 80.0)})
    with pytest.raises(ValidationError, match=r"(?s)marks\.length_mm"):
        SurfaceConfig(marks={"length_mm": (60.0, 15.0)})
    with pytest.raises(ValidationError, match=r"(?s)dirt\.count"):
        SurfaceConfig(dirt={"count": (5, 2)})
    # model_copy does not validate: drawing checks again.
    swapped = BandConfig.model_construct(width_mm=(9.0, 6.0), dn=(30.0, 40.0))
    bad = CLEAN_SURFACE.model_copy(update={"seal": swapped})
    with pytest.raises(ValueError, match=r"surface\.seal\.width_mm"):
        draw_surface(bad, 0, nominal_world(WorldConfig()))
    small = World(np.eye(4), 30.0, 20.0, 2.0)
    with pytest.raises(ValueError, match="do not fit"):
        draw_surface(SurfaceConfig(), 0, small)
    # TOML has no null: false leaves a part out.
    assert RenderConfig.model_validate({"surface": {"seal": False, "paint_band": False}}).surface.seal is None
    with pytest.raises(ValueError, match="strictly decreasing"):
        DrawnSurface(((0.0, 20.0), (1.0, 10.0)), (), (), 150.0, (-50.0, 50.0), (50.0, 50.0), 5.0)


# --- band rendering and the clean surface ---------------------------------------------------------


def test_band_rendering_equals_shading_every_pixel_with_every_feature() -> None:
    config = RenderConfig(
        surface=ALL_ON,
        disturbances=DisturbanceConfig(
            occlusion=OcclusionConfig(edge="top", width_mm=3.0), contrast_factor=0.8, defocus_sigma_px=0.5
        ),
    )
    fast = CameraRenderer(CROP, config)
    slow = CameraRenderer(CROP, config, band_rendering=False)
    world = nominal_world(WorldConfig(corner_radius_mm=10.0))
    T_B_C = camera_pose_seeing_corner(fast.camera, world, (400.0, 120.0), R_T_C=rot_z(0.1) @ rot_x(0.05))
    a, applied_a = fast.render_signal(T_B_C, world, rng=np.random.default_rng(3))
    b, applied_b = slow.render_signal(T_B_C, world, rng=np.random.default_rng(3))
    assert applied_a == applied_b and applied_a.occluded_edge == "top"
    surface = applied_a.surface
    assert surface is not None and len(surface.marks) == 3 and len(surface.dirt) == 25
    contrast = surface.wall_dn - surface.opening_dn
    assert np.max(np.abs(a - b)) <= 1e-6 * contrast
    # The crop really shows the features: the marks' levels and all four steps.
    in_view = [m for m in surface.marks if 0 <= _project(fast, T_B_C, world, m.centre_mm)[0] < 500]
    assert in_view and a.max() > 150.0 and a.min() < 15.0


def _old_shading(renderer: CameraRenderer, T_B_C: np.ndarray, world: World) -> np.ndarray:
    """The renderer's signal before surfaces (a step from the wall to the opening, shaded in every
    pixel), padded to whole blocks as the renderer exposes it."""
    cfg = renderer.config
    blocks = renderer._blocks
    plane = PlaneView.of(world.T_B_T, T_B_C)
    bi, bj = np.nonzero(np.ones((blocks.nby, blocks.nbx), dtype=bool))
    ray_idx, img_idx = blocks.indices(bi, bj)
    X, Y, jac, ok = blocks.pixel_hits(plane, ray_idx)
    half = (world.width_mm / 2, world.height_mm / 2)
    sd, gx, gy = rounded_rect_sdf(X, Y, (-half[0], half[1]), half, world.corner_radius_mm)
    shade = cfg.wall_dn + (cfg.opening_dn - cfg.wall_dn) * coverage_from_sdf(sd, gx, gy, jac, cfg.blur_sigma_px)
    albedo = np.empty(blocks.hp * blocks.wp, dtype=np.float32)
    albedo[img_idx] = np.where(ok, shade, cfg.opening_dn)
    return albedo.reshape(blocks.hp, blocks.wp) * renderer._illumination


def test_clean_surface_renders_the_old_image(world: World) -> None:
    clean = CameraRenderer(CROP, RenderConfig(surface=CLEAN_SURFACE))
    T_B_C = camera_pose_seeing_corner(clean.camera, world, (300.0, 200.0), R_T_C=rot_z(0.08) @ rot_x(0.03))
    signal, applied = clean.render_signal(T_B_C, world)
    assert applied.surface is not None and applied.surface.steps == ((0.0, 20.0),)
    old = _old_shading(clean, T_B_C, world)
    assert np.array_equal(signal, old[: CROP.height_px, : CROP.width_px])
    image = clean.render(T_B_C, world, rng=np.random.default_rng(9)).image
    old_image = clean.expose(old, np.random.default_rng(9))[: CROP.height_px, : CROP.width_px]
    assert np.array_equal(image, old_image)
    # The default surface does change the picture.
    default = CameraRenderer(CROP, RenderConfig()).render_signal(T_B_C, world)[0]
    assert np.max(np.abs(default - signal)) > 10.0
