"""The installed glass in the twin's image: drawn at its true pose (parallax), its greys, band rendering, the camera."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError
from shared_support import edge_crossing

from cellctl.config.loader import load_config
from cellctl.config.mounting import CameraIntrinsics
from cellctl.config.render import DisturbanceConfig, OcclusionConfig, RenderConfig
from cellctl.config.sim import GlassConfig, SimConfig, WorldConfig
from cellctl.geometry.pose import Pose, apply_pose, make_pose
from cellctl.geometry.rotation import rot_x, rot_z, xyz_fixed_to_matrix
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.glass import InstalledGlass, glass_scene
from cellctl.sim.image_truth import camera_pose_seeing_corner
from cellctl.sim.rig import SimRig
from cellctl.sim.world import World, nominal_world

INTR = CameraIntrinsics()
CROP = CameraIntrinsics(width_px=500, height_px=436, cx=INTR.cx - 760.0, cy=INTR.cy - 800.0)
FLAT = {"vignetting_power": 0.0, "lighting_gradient": 0.0}  # illumination exactly 1
WORLD = nominal_world(WorldConfig())
GLASS = GlassConfig()


def _glass(world: World, dx: float, dy: float, dz: float, rx_deg: float = 0.0, ry_deg: float = 0.0, rz_deg: float = 0.0,
           config: GlassConfig = GLASS) -> InstalledGlass:
    E = make_pose(xyz_fixed_to_matrix(*np.radians([rz_deg, ry_deg, rx_deg])), [dx, dy, dz])
    return glass_scene(config, world, world.T_B_T @ E)


def _crossing(profile: np.ndarray, centre: float, half: int = 6) -> float:
    return edge_crossing(profile, centre, half)


def _glass_top_edge_v(renderer: CameraRenderer, T_B_C: Pose, glass: InstalledGlass, columns: np.ndarray) -> np.ndarray:
    """Where the glass's top edge (y_G = gap on its outer surface) truly crosses each pixel column (raw image)."""
    x = np.linspace(-60.0, -20.0, 4001)
    pts = apply_pose(glass.T_B_G, np.column_stack([x, np.full_like(x, glass.edge_gap_mm), np.zeros_like(x)]))
    uv = renderer.project(pts, T_B_C)
    order = np.argsort(uv[:, 0])
    return np.interp(columns, uv[order, 0], uv[order, 1])


def test_the_glass_edge_lies_where_its_true_pose_projects_parallax_included() -> None:
    renderer = CameraRenderer(INTR, RenderConfig(**FLAT))
    T_B_C = camera_pose_seeing_corner(renderer.camera, WORLD, (1600.0, 450.0))  # off-axis: parallax shows
    recessed = _glass(WORLD, 0.2, -0.1, 0.5, rx_deg=0.1, ry_deg=-0.1, rz_deg=0.1)
    flush = _glass(WORLD, 0.2, -0.1, 0.0, rx_deg=0.1, ry_deg=-0.1, rz_deg=0.1)
    signal, applied = renderer.render_signal(T_B_C, WORLD, glass=recessed)
    assert applied.glass is not None and applied.glass.frit_dn == recessed.frit_dn
    columns = np.arange(800.0, 1100.0, 25.0)
    truth = _glass_top_edge_v(renderer, T_B_C, recessed, columns)
    measured = np.array([_crossing(signal[:, int(u)], v) for u, v in zip(columns, truth)])
    assert np.max(np.abs(measured - truth)) < 0.02
    # The recessed glass is seen where it stands, not where a flush one would be (over 0.3 px away here).
    assert np.min(np.abs(_glass_top_edge_v(renderer, T_B_C, flush, columns) - truth)) > 0.3


def test_levels_frit_clear_glass_gap_and_wall() -> None:
    renderer = CameraRenderer(INTR, RenderConfig(**FLAT))
    T_B_C = camera_pose_seeing_corner(renderer.camera, WORLD, (1014.7, 1012.0))
    glass = _glass(WORLD, 0.0, 0.0, 0.0)
    with_glass, applied = renderer.render_signal(T_B_C, WORLD, glass=glass)
    without, _ = renderer.render_signal(T_B_C, WORLD)
    surface = applied.surface
    assert surface is not None
    mm = INTR.fx / 400.0  # px per mm at the wall

    def at(x_mm: float, y_mm: float) -> float:
        return float(with_glass[int(round(1012.0 + y_mm * mm)), int(round(1014.7 + x_mm * mm))])

    flange = surface.steps[1][1]  # the first band inside the opening's edge
    assert at(-50.0, 2.5) == pytest.approx(flange, abs=1e-6)  # the gap shows the flange (it runs on under the glass)
    assert at(-50.0, 15.0) == pytest.approx(glass.frit_dn, abs=1e-6)
    assert at(-50.0, 50.0) == pytest.approx(glass.clear_dn, abs=1e-6)
    # Outside the opening the frame is the same as without a glass.
    outside = np.s_[: int(1012.0 - 1.0 * mm), :]
    assert np.array_equal(with_glass[outside], without[outside])
    # The greys are drawn per car body within their ranges.
    assert GLASS.frit_dn[0] <= glass.frit_dn <= GLASS.frit_dn[1] and GLASS.clear_dn[0] <= glass.clear_dn <= GLASS.clear_dn[1]
    assert glass_scene(GLASS, WORLD, glass.T_B_G) == glass


def test_gap_grey_and_contrast_factor() -> None:
    config = GlassConfig(gap_dn=(70.0, 70.0), frit_dn=(10.0, 10.0), clear_dn=(30.0, 30.0))
    glass = _glass(WORLD, 0.0, 0.0, 0.0, config=config)
    renderer = CameraRenderer(INTR, RenderConfig(**FLAT, disturbances=DisturbanceConfig(contrast_factor=0.5)))
    T_B_C = camera_pose_seeing_corner(renderer.camera, WORLD, (1014.7, 1012.0))
    signal, applied = renderer.render_signal(T_B_C, WORLD, glass=glass)
    mean = 0.5 * (150.0 + 20.0)
    assert applied.glass is not None
    assert applied.glass.frit_dn == pytest.approx(mean + 0.5 * (10.0 - mean))
    assert applied.glass.gap_dn == pytest.approx(mean + 0.5 * (70.0 - mean))
    mm = INTR.fx / 400.0
    assert float(signal[int(1012.0 + 2.5 * mm), int(1014.7 - 50.0 * mm)]) == pytest.approx(applied.glass.gap_dn, abs=1e-6)


def test_band_rendering_equals_shading_every_pixel_with_a_glass() -> None:
    config = RenderConfig(disturbances=DisturbanceConfig(occlusion=OcclusionConfig(edge="top", width_mm=3.0), defocus_sigma_px=0.5))
    fast = CameraRenderer(CROP, config)
    slow = CameraRenderer(CROP, config, band_rendering=False)
    world = nominal_world(WorldConfig(corner_radius_mm=10.0))
    glass = _glass(world, 0.3, -0.2, 0.6, rx_deg=0.1, rz_deg=0.15, config=GlassConfig(frit_width_mm=4.0))
    T_B_C = camera_pose_seeing_corner(fast.camera, world, (380.0, 110.0), R_T_C=rot_z(0.1) @ rot_x(0.05))
    a, applied_a = fast.render_signal(T_B_C, world, rng=np.random.default_rng(3), glass=glass)
    b, applied_b = slow.render_signal(T_B_C, world, rng=np.random.default_rng(3), glass=glass)
    assert applied_a == applied_b
    assert np.max(np.abs(a - b)) <= 1e-6 * (150.0 - 20.0)
    # The crop shows the glass's edge, its frit band and the clear glass beyond.
    assert a.min() < glass.frit_dn + 0.5 and np.any(np.abs(a - glass.clear_dn) < 1e-3)


def test_a_glass_needs_its_car_body() -> None:
    renderer = CameraRenderer(CROP, RenderConfig())
    with pytest.raises(ValueError, match="car body"):
        renderer.render_signal(np.eye(4), None, glass=_glass(WORLD, 0.0, 0.0, 0.0))


async def test_the_rig_camera_sees_the_glass_once_it_is_released() -> None:
    rig = SimRig(SimConfig(seed=5))
    cell = rig.cell
    try:
        cell.execute(cell.install_command())
        assert cell.installed_glass_scene() is None
        T_B_C = camera_pose_seeing_corner(rig.renderer.camera, cell.world(), (1014.7, 1012.0))
        shoot = T_B_C @ np.linalg.inv(cell.T_H_C)
        cell.set_gripper(False)
        scene = cell.installed_glass_scene()
        assert scene is not None and np.array_equal(scene.T_B_G, cell.installed_glass())
        assert cell.installed_glass_scene() is scene  # built once per release
        cell.arm.execute(cell.robot_model.command_for(shoot))
        frame = await rig.camera.grab(timeout_s=30.0)
        assert rig.camera.last_applied is not None and rig.camera.last_applied.glass is not None
        # Well inside the glass's frit band the frame is dark (the opening's flange and seal would be brighter).
        mm = INTR.fx / 400.0
        assert np.median(frame.image[int(1012 + 12 * mm) : int(1012 + 20 * mm), 300:700]) < 25
        cell.new_car_body()
        assert cell.installed_glass_scene() is None
    finally:
        await rig.close()


def test_glass_config_names_the_field() -> None:
    with pytest.raises(ValidationError, match="sim.glass.edge_gap_mm"):
        SimConfig(glass=GlassConfig(edge_gap_mm=30.0))
    with pytest.raises(ValidationError, match="frit_width_mm"):
        GlassConfig(height_mm=60.0, frit_width_mm=26.0)
    with pytest.raises(ValidationError, match="frit_dn"):
        GlassConfig(frit_dn=(10.0, 300.0))
    with pytest.raises(ValidationError, match="laser_dropout_probability"):
        GlassConfig(laser_dropout_probability=1.0)
    assert GlassConfig.model_validate({"gap_dn": False}).gap_dn is None
    with pytest.raises(ValueError, match="corner radius"):
        glass_scene(GLASS, World(np.eye(4), 2000.0, 1500.0, 2.0), np.eye(4))
    sim = load_config("config/sim.toml").sim.glass
    assert (sim.edge_gap_mm, sim.thickness_mm, sim.frit_width_mm) == (5.0, 6.0, 25.0)
