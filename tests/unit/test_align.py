"""Paper section 3 against known truth: eq. 1, eq. 2-11, the reversal rule, eq. 13, eq. 14."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.align import (
    AlignmentError,
    camera_distance_to_plane,
    compute_alignment,
    fit_wall_plane,
    laser_points,
    plan_spot_poses,
    solve_orientation_lm,
    solve_orientation_minimal,
)
from cellctl.config import CellConfig
from cellctl.geometry import (
    angle_between_vectors,
    fit_plane,
    make_pose,
    minimal_rotation,
    rot_x,
    rot_y,
    rot_z,
)

CONFIG = CellConfig()
LASER = CONFIG.sim.laser
T_H_C = CONFIG.sim.camera.hand_eye.T_H_C()
R_SHOOT = CONFIG.sim.world.T_B_T_nominal()[:3, :3] @ T_H_C[:3, :3].T


def true_wall(rng: np.random.Generator) -> np.ndarray:
    """A wall frame W (z into the wall) tilted a few degrees from the nominal T, in B."""
    T_nom = CONFIG.sim.world.T_B_T_nominal()
    tilt = rot_x(rng.uniform(-0.05, 0.05)) @ rot_y(rng.uniform(-0.05, 0.05)) @ rot_z(rng.uniform(-0.05, 0.05))
    T = make_pose(T_nom[:3, :3] @ tilt, T_nom[:3, 3] + rng.uniform(-20, 20, 3))
    return T


def spots_over_a_metre() -> np.ndarray:
    """Six spot targets (x, y in mm on the wall) spread over about 1 m."""
    return np.array([[-1000.0, -60.0], [-300.0, -60.0], [60.0, 100.0], [60.0, 700.0], [-500.0, 900.0], [-1000.0, 500.0]])


def measure(
    T_B_W: np.ndarray,
    commanded: np.ndarray,
    rng: np.random.Generator,
    robot_sigma_mm: float = 0.0,
    linearity_mm: float = 0.0,
) -> np.ndarray:
    """True laser distances from noisy actual flange poses to the plane z_W = 0."""
    n = T_B_W[:3, 2]
    D = n @ T_B_W[:3, 3]
    out = []
    for T_cmd in commanded:
        R = T_cmd[:3, :3]
        p = T_cmd[:3, 3] + rng.normal(0.0, robot_sigma_mm, 3)
        o = R @ LASER.r + p
        d = R @ LASER.l
        out.append((D - n @ o) / (n @ d) + rng.uniform(-linearity_mm, linearity_mm))
    return np.array(out)


def test_laser_points_eq1() -> None:
    T = make_pose(rot_z(0.3), [100.0, 200.0, 300.0])
    p = laser_points(T[None], LASER.r, LASER.l, [350.0])
    np.testing.assert_allclose(p[0], T[:3, :3] @ (LASER.r + 350.0 * LASER.l) + T[:3, 3], atol=1e-12)


def test_noise_free_spots_give_the_plane_to_1e9() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        T_B_W = true_wall(rng)
        cmd = plan_spot_poses(CONFIG.sim.world.T_B_T_nominal(), spots_over_a_metre(), R_SHOOT, LASER.r, LASER.l, 350.0)
        d = measure(T_B_W, cmd, rng)
        wall = fit_wall_plane(laser_points(cmd, LASER.r, LASER.l, d), cmd[:, :3, 3])
        assert angle_between_vectors(wall.normal, T_B_W[:3, 2]) < 1e-9
        assert abs(wall.offset - T_B_W[:3, 2] @ T_B_W[:3, 3]) < 1e-9 * 2000
        assert wall.plane.rms < 1e-9 and wall.rejected == ()


def test_normal_points_into_the_wall_whatever_the_eigenvector_sign() -> None:
    pts = np.array([[1000.0, 0, 0], [1000.0, 500, 0], [1000.0, 0, 500], [1000.0, 400, 400]])
    sensor = np.array([600.0, 200.0, 200.0])
    for flip in (1.0, -1.0):
        wall = fit_wall_plane(pts * np.array([1, flip, 1]), sensor)
        np.testing.assert_allclose(wall.normal, [1, 0, 0], atol=1e-12)
        assert wall.offset == pytest.approx(1000.0)


def test_plane_fit_reports_quality_figures() -> None:
    pts = np.array([[0.0, 0, 0.1], [1000, 0, -0.1], [0, 1000, -0.1], [1000, 1000, 0.1]])
    fit = fit_plane(pts)
    np.testing.assert_allclose(np.abs(fit.normal), [0, 0, 1], atol=1e-6)
    assert fit.rms == pytest.approx(0.1, rel=1e-6)
    assert fit.max_residual == pytest.approx(0.1, rel=1e-6)
    assert fit.eigenvalues[0] < fit.eigenvalues[1] <= fit.eigenvalues[2]
    assert fit.planarity < 1e-7 and fit.collinearity == pytest.approx(1.0)


def test_robust_fit_rejects_a_spot_in_a_recess_and_says_why() -> None:
    rng = np.random.default_rng(5)
    pts = np.column_stack([np.full(8, 1500.0), rng.uniform(-500, 500, 8), rng.uniform(-500, 500, 8)])
    pts[:, 0] += rng.normal(0, 0.02, 8)
    pts[4, 0] += 3.0  # a spot that fell 3 mm deeper (a seal groove)
    wall = fit_wall_plane(pts, np.array([1100.0, 0, 0]), inlier_threshold_mm=0.5)
    assert [s.index for s in wall.rejected] == [4]
    assert wall.rejected[0].residual_mm == pytest.approx(3.0, abs=0.1)
    assert "behind the plane" in wall.rejected[0].reason
    assert 4 not in wall.inliers and len(wall.inliers) == 7
    np.testing.assert_allclose(wall.normal, [1, 0, 0], atol=1e-4)


def test_lm_and_minimal_orientation_give_the_same_camera_axis() -> None:
    rng = np.random.default_rng(11)
    z_C = T_H_C[:3, 2]
    for _ in range(200):
        R0 = R_SHOOT @ rot_x(rng.uniform(-0.1, 0.1)) @ rot_y(rng.uniform(-0.1, 0.1))
        n = minimal_rotation([1, 0, 0], [1, rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1)]) @ [1, 0, 0]
        lm = solve_orientation_lm(R0, z_C, n)
        mini = solve_orientation_minimal(R0, z_C, n)
        assert lm.axis_error_rad < 1e-9 and mini.axis_error_rad < 1e-12
        assert angle_between_vectors(lm.R_B_H @ z_C, mini.R_B_H @ z_C) < 1e-9
        # Both stay close to the start: the correction is a few degrees, not a spin.
        assert angle_between_vectors(lm.R_B_H[:, 0], R0[:, 0]) < 0.3


def test_minimal_orientation_adds_no_spin_about_the_normal() -> None:
    z_C = T_H_C[:3, 2]
    n = np.array([1.0, 0.02, -0.03])
    n /= np.linalg.norm(n)
    mini = solve_orientation_minimal(R_SHOOT, z_C, n)
    delta = mini.R_B_H @ R_SHOOT.T
    from cellctl.geometry import matrix_to_axis_angle

    axis = matrix_to_axis_angle(delta)
    assert abs(axis @ n) < 1e-12 and abs(axis @ (R_SHOOT @ z_C)) < 1e-12


def test_distance_correction_eq14_reaches_the_working_distance() -> None:
    rng = np.random.default_rng(2)
    T_B_W = true_wall(rng)
    cmd = plan_spot_poses(CONFIG.sim.world.T_B_T_nominal(), spots_over_a_metre(), R_SHOOT, LASER.r, LASER.l, 350.0)
    d = measure(T_B_W, cmd, rng)
    res = compute_alignment(cmd, d, LASER.r, LASER.l, T_H_C, 400.0)
    T_B_C = res.T_B_H_aligned @ T_H_C
    assert angle_between_vectors(T_B_C[:3, 2], T_B_W[:3, 2]) < 1e-9
    assert camera_distance_to_plane(res.T_B_H_aligned, T_H_C, res.wall.plane) == pytest.approx(400.0, abs=1e-9)
    # The move of eq. 14 lies along the camera's z axis expressed in the flange frame.
    np.testing.assert_allclose(res.distance.delta_H_mm, T_H_C[:3, 2] * res.distance.delta_d_mm, atol=1e-9)
    # The optical centre kept its place in the wall plane: only the normal coordinate changed.
    p_before = (cmd[-1] @ T_H_C)[:3, 3]
    shift = T_B_C[:3, 3] - p_before
    assert np.linalg.norm(shift - (shift @ res.wall.normal) * res.wall.normal) < 1e-6


def test_1000_noisy_trials_camera_axis_within_0_05_deg_p99_and_uncertainty_honest() -> None:
    """LK-G500 linearity +-0.02 % of 200 mm and robot repeatability 0.1 mm, 6 spots over ~1 m."""
    rng = np.random.default_rng(20261122)
    T_nom = CONFIG.sim.world.T_B_T_nominal()
    observed, predicted = [], []
    for _ in range(1000):
        T_B_W = true_wall(rng)
        cmd = plan_spot_poses(T_nom, spots_over_a_metre(), R_SHOOT, LASER.r, LASER.l, 350.0)
        d = measure(T_B_W, cmd, rng, robot_sigma_mm=0.1, linearity_mm=0.0002 * 200.0)
        res = compute_alignment(cmd, d, LASER.r, LASER.l, T_H_C, 400.0, range_mm=(250.0, 450.0))
        axis = (res.T_B_H_aligned @ T_H_C)[:3, 2]
        observed.append(angle_between_vectors(axis, T_B_W[:3, 2]))
        predicted.append(res.wall.uncertainty.rms_rad)
    observed_deg = np.degrees(observed)
    assert np.percentile(observed_deg, 99) < 0.05
    rms_observed = np.sqrt(np.mean(np.square(observed)))
    rms_predicted = np.sqrt(np.mean(np.square(predicted)))
    assert 1 / 1.5 < rms_predicted / rms_observed < 1.5


@pytest.mark.parametrize(
    ("points", "match"),
    [
        (np.zeros((2, 3)), "at least 3 points"),
        (np.array([[0.0, 0, 0], [1, 1, 1], [np.nan, 0, 0]]), "NaN"),
        (np.ones((5, 3)), "coincide"),
        (np.array([[0.0, 0, 0], [100, 0, 0], [200, 0, 0], [300, 0, 0]]), "collinear"),
    ],
)
def test_degenerate_spots_are_refused_with_the_reason(points: np.ndarray, match: str) -> None:
    with pytest.raises(AlignmentError, match=match):
        fit_wall_plane(points, np.array([-500.0, 0, 0]))


def test_collinear_message_carries_the_condition_figure() -> None:
    pts = np.array([[0.0, 0, 0], [100, 0, 0], [200, 0.001, 0], [300, 0, 0]])
    with pytest.raises(AlignmentError, match=r"lambda_mid/lambda_max = [0-9.e-]+"):
        fit_wall_plane(pts, np.array([0.0, 0, -500.0]))


def test_bad_laser_inputs_are_refused() -> None:
    T = np.eye(4)[None].repeat(3, axis=0)
    with pytest.raises(AlignmentError, match="length 1.0100"):
        laser_points(T, LASER.r, np.array([1.01, 0, 0]), [300, 300, 300])
    with pytest.raises(AlignmentError, match="outside the sensor's range 250..450"):
        laser_points(T, LASER.r, LASER.l, [300, 460, 300], range_mm=(250, 450))
    with pytest.raises(AlignmentError, match="not finite"):
        laser_points(T, LASER.r, LASER.l, [300, np.inf, 300])
    with pytest.raises(AlignmentError, match="3 flange poses but 2 distances"):
        laser_points(T, LASER.r, LASER.l, [300, 300])


def test_bad_fit_is_refused_by_the_rms_gate() -> None:
    rng = np.random.default_rng(1)
    pts = np.column_stack([1500 + rng.normal(0, 0.3, 10), rng.uniform(-500, 500, 10), rng.uniform(-500, 500, 10)])
    with pytest.raises(AlignmentError, match="RMS"):
        fit_wall_plane(pts, np.array([1000.0, 0, 0]), inlier_threshold_mm=5.0, max_rms_mm=0.1)
