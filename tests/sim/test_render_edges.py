"""The rendered window edges and corner against the projected truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from cellctl.config.mounting import CameraIntrinsics
from cellctl.config.render import DisturbanceConfig, OcclusionConfig, RenderConfig
from cellctl.config.sim import WorldConfig
from cellctl.geometry.pose import invert_pose
from cellctl.geometry.rotation import rot_x, rot_y, rot_z
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.edge_coverage import edge_coverage
from cellctl.sim.image_truth import (
    EdgeName,
    camera_pose_seeing_corner,
    corner_truth,
    edge_curve_px,
    straight_range_mm,
)
from cellctl.sim.world import World, nominal_world, sample_world

INTR = CameraIntrinsics()
CONFIG = RenderConfig()


@pytest.fixture(scope="module")
def renderer() -> CameraRenderer:
    return CameraRenderer(INTR, CONFIG)


@pytest.fixture(scope="module")
def world() -> World:
    return sample_world(WorldConfig(), np.random.default_rng(7))


# --- the anti-aliasing profile -------------------------------------------------------------------


@pytest.mark.parametrize("angle_deg", [0.0, 17.0, 45.0, 71.0])
@pytest.mark.parametrize("sigma", [0.0, 0.5, 1.2])
def test_edge_coverage_equals_the_pixel_integral_of_the_blurred_half_plane(angle_deg: float, sigma: float) -> None:
    """Numerically integrate Phi(signed distance / sigma) over the pixel square."""
    m = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
    n = 400
    s = (np.arange(n) + 0.5) / n - 0.5
    du, dv = np.meshgrid(s, s)
    from scipy.special import ndtr

    for d in [-2.0, -0.9, -0.3, 0.0, 0.2, 0.6, 1.4]:
        inside = d + du * m[0] + dv * m[1]  # signed distance of each footprint point, inside > 0
        numeric = np.mean(ndtr(inside / sigma)) if sigma > 0 else np.mean(inside > 0)
        exact = edge_coverage(np.array([d]), np.array([m[0]]), np.array([m[1]]), sigma)[0]
        assert abs(exact - numeric) < 2e-3 if sigma == 0 else abs(exact - numeric) < 1e-5
    half = edge_coverage(np.array([0.0]), np.array([m[0]]), np.array([m[1]]), sigma)[0]
    assert half == pytest.approx(0.5, abs=1e-12)


# --- edges of a noise-free render ----------------------------------------------------------------


def _crossing(profile: np.ndarray, centre: float, half: int = 7) -> float:
    """The interpolated 50 % crossing of a 1-D edge profile near ``centre``.

    The levels on either side are the means of the three outermost samples of a +-``half`` px
    window; a cubic spline through the samples is intersected with their mid level.
    """
    k0 = int(np.floor(centre))
    pos = np.arange(k0 - half, k0 + half + 2)
    vals = profile[pos].astype(float)
    level = 0.5 * (vals[:3].mean() + vals[-3:].mean())
    spline = CubicSpline(pos, vals - level)
    roots = [r for r in spline.roots(extrapolate=False) if pos[3] <= r <= pos[-4]]
    assert len(roots) == 1, f"expected one crossing near {centre:.2f}, got {roots}"
    return float(roots[0])


def _edge_errors(
    image: np.ndarray, renderer: CameraRenderer, T_B_C: np.ndarray, world: World, edge: EdgeName
) -> tuple[np.ndarray, float]:
    """Distance (px, along the scanline) from the 50 % crossing to the projected true edge curve,
    and how far that curve bends away from the straight chord between its visible ends (px)."""
    a0, a1 = straight_range_mm(world, edge)
    a = np.linspace(a0 + 3.0, a1, 200001)  # 3 mm clear of the arc's end; ~0.01 mm steps
    curve = edge_curve_px(renderer.camera, T_B_C, world, edge, a)
    across, along = (1, 0) if edge == "top" else (0, 1)  # top edge: scan columns; right edge: rows
    inside = (
        (curve[:, 0] > 12)
        & (curve[:, 0] < INTR.width_px - 13)
        & (curve[:, 1] > 12)
        & (curve[:, 1] < INTR.height_px - 13)
    )
    curve = curve[inside]
    order = np.argsort(curve[:, along])
    c_along, c_across = curve[order, along], curve[order, across]
    errors = []
    for line in range(int(np.ceil(c_along[0])), int(c_along[-1]), 5):
        true_pos = float(np.interp(line, c_along, c_across))
        profile = image[:, line] if edge == "top" else image[line, :]
        errors.append(_crossing(profile, true_pos) - true_pos)
    assert len(errors) > 60
    chord = curve[order[-1]] - curve[order[0]]
    normal = np.array([-chord[1], chord[0]]) / np.linalg.norm(chord)
    bend = float(np.max(np.abs((curve - curve[order[0]]) @ normal)))
    return np.array(errors), bend


@pytest.mark.parametrize(
    "corner_px, tilt",
    [
        ((1500.0, 560.0), (0.0, 0.0, 0.0)),
        ((1350.0, 700.0), (0.04, -0.05, 0.12)),
        ((1700.0, 300.0), (-0.03, 0.06, -0.3)),
    ],
)
def test_noise_free_edges_lie_on_the_projected_true_edges(
    renderer: CameraRenderer, world: World, corner_px: tuple[float, float], tilt: tuple[float, float, float]
) -> None:
    R = rot_x(tilt[0]) @ rot_y(tilt[1]) @ rot_z(tilt[2])
    T_B_C = camera_pose_seeing_corner(renderer.camera, world, corner_px, distance_mm=400.0, R_T_C=R)
    image = renderer.render(T_B_C, world, noise=False).image  # 8-bit, rounded, no noise
    for edge in ("top", "right"):
        err, bend = _edge_errors(image, renderer, T_B_C, world, edge)
        assert np.max(np.abs(err)) < 0.05, f"{edge} edge: worst {np.max(np.abs(err)):.3f} px"
        assert abs(np.mean(err)) < 0.01
        # The check has teeth: distortion bends the edge visibly, so a straight-line truth
        # (ignoring distortion) would be off by more than the tolerance.
        assert bend > 0.3, f"{edge} edge bends only {bend:.2f} px"


def test_render_and_cv2_project_points_agree_on_the_corner(renderer: CameraRenderer, world: World) -> None:
    """Fit the two straight edges of a noise-free render, intersect them, and compare the corner
    with cv2.projectPoints of the workpiece frame's origin."""
    R = rot_x(0.03) @ rot_y(-0.02) @ rot_z(0.08)
    T_B_C = camera_pose_seeing_corner(renderer.camera, world, (1450.0, 620.0), distance_mm=405.0, R_T_C=R)
    image = renderer.render(T_B_C, world, noise=False).image
    K, D = INTR.camera_matrix(), INTR.dist_coeffs()
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    lines = []
    for edge in ("top", "right"):
        a0, a1 = straight_range_mm(world, edge)
        a = np.linspace(a0 + 3.0, a1, 100001)
        curve = edge_curve_px(renderer.camera, T_B_C, world, edge, a)
        ok = (curve[:, 0] > 12) & (curve[:, 0] < 2035) & (curve[:, 1] > 12) & (curve[:, 1] < 2035)
        curve = curve[ok]
        along = 0 if edge == "top" else 1
        order = np.argsort(curve[:, along])
        pts = []
        for line in range(int(np.ceil(curve[order[0], along])), int(curve[order[-1], along]), 4):
            guess = float(np.interp(line, curve[order, along], curve[order, 1 - along]))
            if edge == "top":
                pts.append((line, _crossing(image[:, line], guess)))
            else:
                pts.append((_crossing(image[line, :], guess), line))
        # Undistort the edge points with OpenCV, then fit a straight line (total least squares).
        und = cv2.undistortPointsIter(
            np.array(pts, dtype=np.float64).reshape(-1, 1, 2), K, D, None, None, crit
        ).reshape(-1, 2)
        centre = und.mean(axis=0)
        _, _, vt = np.linalg.svd(und - centre)
        lines.append((centre, vt[0]))
    (p, d), (q, e) = lines
    s, _ = np.linalg.solve(np.column_stack([d, -e]), q - p)
    corner_norm = p + s * d
    measured, _ = cv2.projectPoints(np.array([[corner_norm[0], corner_norm[1], 1.0]]), np.zeros(3), np.zeros(3), K, D)
    T_C_T = invert_pose(T_B_C) @ world.T_B_T
    rvec, _ = cv2.Rodrigues(T_C_T[:3, :3])
    expected, _ = cv2.projectPoints(np.zeros((1, 3)), rvec, T_C_T[:3, 3], K, D)
    err = np.linalg.norm(measured.reshape(2) - expected.reshape(2))
    assert err < 0.03, f"corner from the render is {err:.4f} px from cv2.projectPoints"
    # The truth helper says the same.
    truth = corner_truth(renderer.camera, T_B_C, world)
    assert np.linalg.norm(truth.corner_px - expected.reshape(2)) < 1e-6
    assert np.linalg.norm(truth.corner_px - np.array([1450.0, 620.0])) < 1e-6


def test_corner_truth_directions_and_angle() -> None:
    world = nominal_world(WorldConfig())
    camera = CameraRenderer(INTR, CONFIG).camera
    T_B_C = camera_pose_seeing_corner(camera, world, (1024.0, 1024.0), R_T_C=rot_z(np.radians(2.0)))
    truth = corner_truth(camera, T_B_C, world)
    # Camera turned +2 deg about its optical axis: the wall (and the top edge) turns -2 deg, seen
    # through the slightly different focal lengths fx, fy.
    expected = np.arctan(INTR.fy / INTR.fx * np.tan(np.radians(-2.0)))
    assert truth.edge_angle_rad == pytest.approx(expected, abs=1e-9)
    assert truth.corner_angle_rad == pytest.approx(np.pi / 2, abs=1e-3)
    assert truth.top_edge_dir_px[0] < -0.99 and truth.right_edge_dir_px[1] > 0.99
    assert truth.corner_in_image and truth.depth_mm == pytest.approx(400.0)


# --- band rendering is exact -----------------------------------------------------------------------


def test_band_rendering_equals_shading_every_pixel() -> None:
    # A 500 x 436 crop of the paper's camera (principal point shifted accordingly): not a whole
    # number of 16 px blocks, to exercise the padding too.
    crop = CameraIntrinsics(width_px=500, height_px=436, cx=INTR.cx - 760.0, cy=INTR.cy - 800.0)
    config = RenderConfig(disturbances=DisturbanceConfig(occlusion=OcclusionConfig(edge="top", width_mm=3.0)))
    fast = CameraRenderer(crop, config)
    slow = CameraRenderer(crop, config, band_rendering=False)
    world = nominal_world(WorldConfig(corner_radius_mm=10.0))
    T_B_C = camera_pose_seeing_corner(fast.camera, world, (400.0, 120.0), R_T_C=rot_z(0.1) @ rot_x(0.05))
    a, applied_a = fast.render_signal(T_B_C, world, rng=np.random.default_rng(3))
    b, applied_b = slow.render_signal(T_B_C, world, rng=np.random.default_rng(3))
    assert applied_a == applied_b and applied_a.occluded_edge == "top"
    assert a.shape == (436, 500)
    assert np.max(np.abs(a - b)) < 1e-3  # DN; float32 rounding, far below one grey level
    # Both really contain the edges (not a blank wall).
    assert a.max() - a.min() > 100
