"""Sensor noise, lighting and the optional disturbances of the twin camera, against their models."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config.mounting import CameraIntrinsics
from cellctl.config.render import DisturbanceConfig, GlareConfig, OcclusionConfig, RenderConfig
from cellctl.config.sim import WorldConfig
from cellctl.config.surface import CLEAN_SURFACE
from cellctl.geometry.rotation import rot_z
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.image_truth import camera_pose_seeing_corner, edge_curve_px, straight_range_mm
from cellctl.sim.world import World, nominal_world

INTR = CameraIntrinsics()
WORLD = nominal_world(WorldConfig())
# Camera poses: the corner far up-left of the image (all wall), far up-right (all opening), and
# the corner in view at the upper right (the shooting view).
ALL_WALL = (-3000.0, -3000.0)
ALL_OPENING = (5000.0, -3000.0)
CORNER_VIEW = (1500.0, 560.0)


def _pose(renderer: CameraRenderer, corner_px: tuple[float, float], world: World = WORLD) -> np.ndarray:
    return camera_pose_seeing_corner(renderer.camera, world, corner_px, R_T_C=rot_z(0.03))


@pytest.fixture(scope="module")
def renderer() -> CameraRenderer:
    return CameraRenderer(INTR, RenderConfig())


def test_shot_and_read_noise_have_the_modelled_variance(renderer: CameraRenderer) -> None:
    T = _pose(renderer, ALL_WALL)
    clean, _ = renderer.render_signal(T, WORLD)
    noisy = renderer.render(T, WORLD, rng=np.random.default_rng(1)).image.astype(np.float64)
    cfg = renderer.config
    residual = noisy - clean - cfg.black_level_dn
    # Shot noise (signal / gain), read noise, and the rounding to whole grey levels (1/12).
    expected_var = clean / cfg.electrons_per_dn + cfg.read_noise_dn**2 + 1.0 / 12.0
    ratio = residual.var() / expected_var.mean()
    assert ratio == pytest.approx(1.0, abs=0.02)
    assert abs(residual.mean()) < 0.01


def test_low_counts_get_exact_poisson_noise() -> None:
    # 0.5 electrons per grey level and a 20 DN interior: 10 electrons per pixel, so every pixel
    # shows a whole number of electrons, i.e. an even number of grey levels above the black level.
    config = RenderConfig(
        electrons_per_dn=0.5, read_noise_dn=0.0, black_level_dn=10.0, vignetting_power=0.0, lighting_gradient=0.0
    )
    r = CameraRenderer(INTR, config)
    image = r.render(_pose(r, ALL_OPENING), WORLD, rng=np.random.default_rng(2)).image.astype(np.int64)
    counts = image - 10
    assert np.all(counts % 2 == 0)
    electrons = counts // 2
    assert electrons.mean() == pytest.approx(10.0, abs=0.02)
    assert electrons.var() == pytest.approx(10.0, rel=0.02)  # Poisson: variance = mean
    # Skewed like a Poisson law, unlike a normal approximation: P(0) = e^-10.
    assert np.mean(electrons == 0) == pytest.approx(np.exp(-10.0), abs=3e-5)


def test_lighting_is_vignetting_times_the_gradient(renderer: CameraRenderer) -> None:
    clean, _ = renderer.render_signal(_pose(renderer, ALL_WALL), WORLD)
    cfg = renderer.config
    phi = np.radians(cfg.lighting_gradient_angle_deg)
    for u, v in [(1014, 1012), (0, 0), (2047, 0), (0, 2047), (2047, 2047), (300, 1700)]:
        x, y = renderer.camera.undistort_pixels([[u, v]])[0]
        cos4 = (1.0 / (1.0 + x * x + y * y)) ** (cfg.vignetting_power / 2.0)
        ramp = 1.0 + cfg.lighting_gradient * (np.cos(phi) * (u - INTR.cx) + np.sin(phi) * (v - INTR.cy)) / INTR.width_px
        assert clean[v, u] == pytest.approx(cfg.wall_dn * cos4 * ramp, rel=1e-5)
    # Uneven indeed: the corners differ from each other by several grey levels.
    assert clean[2047, 2047] - clean[0, 0] > 5.0


def test_renders_are_reproducible_for_a_seed(renderer: CameraRenderer) -> None:
    T = _pose(renderer, CORNER_VIEW)
    a = renderer.render(T, WORLD, rng=np.random.default_rng(9)).image
    b = renderer.render(T, WORLD, rng=np.random.default_rng(9)).image
    c = renderer.render(T, WORLD, rng=np.random.default_rng(10)).image
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    with pytest.raises(ValueError, match="seeded numpy Generator"):
        renderer.render(T, WORLD)


def _distance_to_edges(renderer: CameraRenderer, T: np.ndarray, point: tuple[float, float]) -> float:
    best = np.inf
    for edge in ("top", "right"):
        a0, a1 = straight_range_mm(WORLD, edge)
        curve = edge_curve_px(renderer.camera, T, WORLD, edge, np.linspace(a0, a1, 20001))
        best = min(best, float(np.min(np.linalg.norm(curve - np.asarray(point), axis=1))))
    return best


def test_glare_spot_sits_on_a_visible_edge_and_saturates() -> None:
    glare = GlareConfig(peak_dn=150.0, sigma_px=50.0)
    r = CameraRenderer(INTR, RenderConfig(disturbances=DisturbanceConfig(glare=glare)))
    T = _pose(r, CORNER_VIEW)
    centres = []
    for seed in (1, 2, 3):
        frame = r.render(T, WORLD, rng=np.random.default_rng(seed))
        c = frame.applied.glare_center_px
        assert c is not None and frame.applied.glare_peak_dn == 150.0
        assert _distance_to_edges(r, T, c) < 0.75 * glare.sigma_px
        u, v = int(round(c[0])), int(round(c[1]))
        patch = frame.image[v - 25 : v + 26, u - 25 : u + 26]
        assert patch.max() == 255  # the wall side of the spot is washed out
        centres.append(c)
    assert len({tuple(np.round(c, 3)) for c in centres}) == 3  # drawn per frame from the seed


@pytest.mark.parametrize("kind", ["wall_like", "dark"])
def test_occlusion_hides_a_stretch_of_one_edge(kind: str) -> None:
    occ = OcclusionConfig(edge="top", edge_fraction=0.3, width_mm=4.0, kind=kind)
    r = CameraRenderer(INTR, RenderConfig(surface=CLEAN_SURFACE, disturbances=DisturbanceConfig(occlusion=occ)))
    T = _pose(r, CORNER_VIEW)
    signal, applied = r.render_signal(T, WORLD, rng=np.random.default_rng(5))
    assert applied.occluded_edge == "top" and applied.occluded_span_mm is not None
    lo, hi = applied.occluded_span_mm
    a0, a1 = straight_range_mm(WORLD, "top")
    visible_length = (hi - lo) / 0.3
    assert a0 <= lo < hi <= a1 and visible_length > 50.0
    # Probe 1 mm off the edge, into the opening (wall-like occluder) or onto the wall (dark strip).
    side = 1.0 if kind == "wall_like" else -1.0
    mid_inside = 0.5 * (lo + hi)
    outside = lo - 5.0 if lo - 5.0 > a0 + 5.0 else hi + 5.0
    probes = np.array([[-mid_inside, side, 0.0], [-outside, side, 0.0]])
    uv = r.project(probes @ WORLD.T_B_T[:3, :3].T + WORLD.T_B_T[:3, 3], T)
    inside_val, outside_val = (float(signal[int(round(p[1])), int(round(p[0]))]) for p in uv)
    if kind == "wall_like":
        assert inside_val > 100.0 and outside_val < 30.0  # wall shows where the opening was
    else:
        assert inside_val < 30.0 and outside_val > 100.0  # dark where the wall was


def test_low_contrast_halves_the_step_about_its_mean() -> None:
    renderer = CameraRenderer(INTR, RenderConfig(surface=CLEAN_SURFACE))
    low = CameraRenderer(INTR, RenderConfig(surface=CLEAN_SURFACE, disturbances=DisturbanceConfig(contrast_factor=0.5)))
    T = _pose(renderer, CORNER_VIEW)
    full, _ = renderer.render_signal(T, WORLD)
    half, applied = low.render_signal(T, WORLD)
    assert (applied.wall_dn, applied.opening_dn) == pytest.approx((117.5, 52.5))  # mean 85 kept
    wall_px, open_px = (100, 200), (1200, 1400)  # (v, u): wall above the top edge, opening inside
    assert half[wall_px] / full[wall_px] == pytest.approx(117.5 / 150.0, rel=1e-5)
    assert half[open_px] / full[open_px] == pytest.approx(52.5 / 20.0, rel=1e-5)


def test_defocus_softens_the_edge_without_moving_it(renderer: CameraRenderer) -> None:
    soft = CameraRenderer(INTR, RenderConfig(disturbances=DisturbanceConfig(defocus_sigma_px=1.5)))
    T = _pose(renderer, CORNER_VIEW)
    sharp_img, _ = renderer.render_signal(T, WORLD)
    soft_img, applied = soft.render_signal(T, WORLD)
    assert applied.blur_sigma_px == pytest.approx(np.hypot(0.8, 1.5))
    a0, a1 = straight_range_mm(WORLD, "top")
    for u in (200, 500, 800):
        curve = edge_curve_px(renderer.camera, T, WORLD, "top", np.linspace(a0, a1, 20001))
        v_true = float(np.interp(u, curve[::-1, 0], curve[::-1, 1]))
        col_sharp = sharp_img[int(v_true) - 10 : int(v_true) + 11, u].astype(float)
        col_soft = soft_img[int(v_true) - 10 : int(v_true) + 11, u].astype(float)
        slope_ratio = np.max(np.abs(np.diff(col_soft))) / np.max(np.abs(np.diff(col_sharp)))
        assert slope_ratio < 0.65
        # The 50 % level still sits on the true edge (linear interpolation between samples).
        for col in (col_sharp, col_soft):
            level = 0.5 * (col[:3].mean() + col[-3:].mean())
            k = int(np.flatnonzero((col[:-1] - level) * (col[1:] - level) <= 0)[0])
            crossing = int(v_true) - 10 + k + (level - col[k]) / (col[k + 1] - col[k])
            assert abs(crossing - v_true) < 0.05
