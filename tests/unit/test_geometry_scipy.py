"""The geometry kernel against scipy's Rotation as an independent oracle: random rotations, round trips, conventions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cellctl.geometry import (
    axis_angle_to_matrix,
    matrix_to_axis_angle,
    matrix_to_quat,
    matrix_to_xyz_fixed,
    matrix_to_zyx_euler,
    mean_pose,
    minimal_rotation,
    nearest_rotation,
    quat_to_matrix,
    rot_x,
    rot_y,
    rot_z,
    rotation_angle_between,
    xyz_fixed_to_matrix,
    zyx_euler_to_matrix,
)
from cellctl.geometry.pose import make_pose

TOL = 1e-12
N = 500


@pytest.fixture(scope="module")
def rotations() -> Rotation:
    """N uniformly random rotations, with the identity and exact half turns mixed in."""
    special = Rotation.from_rotvec([[0.0, 0.0, 0.0], [np.pi, 0, 0], [0, np.pi, 0], [0, 0, np.pi], [0.6 * np.pi, -0.8 * np.pi, 0]])
    return Rotation.concatenate([special, Rotation.random(N, random_state=17)])


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles folded into (-pi, pi]: +pi and -pi are the same angle."""
    return np.angle(np.exp(1j * np.asarray(a)))


def test_elementary_rotations_are_scipys_active_rotations() -> None:
    for angle in (-2.5, -0.3, 0.0, 1e-9, 0.7, np.pi):
        np.testing.assert_allclose(rot_x(angle), Rotation.from_euler("x", angle).as_matrix(), atol=TOL)
        np.testing.assert_allclose(rot_y(angle), Rotation.from_euler("y", angle).as_matrix(), atol=TOL)
        np.testing.assert_allclose(rot_z(angle), Rotation.from_euler("z", angle).as_matrix(), atol=TOL)


def test_quaternions_are_scipys_in_abb_order_with_w_non_negative(rotations: Rotation) -> None:
    for r in rotations:
        R = r.as_matrix()
        q = matrix_to_quat(R)
        x, y, z, w = r.as_quat()
        assert q[0] >= 0.0
        assert np.allclose(q, [w, x, y, z], atol=TOL) or np.allclose(q, [-w, -x, -y, -z], atol=TOL)
        np.testing.assert_allclose(quat_to_matrix(q), R, atol=TOL)
        np.testing.assert_allclose(Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix(), R, atol=TOL)


def test_quat_to_matrix_normalises_as_scipy_does() -> None:
    rng = np.random.default_rng(3)
    for q in rng.normal(size=(N, 4)) * rng.uniform(1e-3, 1e3, size=(N, 1)):
        np.testing.assert_allclose(quat_to_matrix(q), Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix(), atol=TOL)


def test_eq13_fixed_angles_are_scipys_extrinsic_xyz(rotations: Rotation) -> None:
    rng = np.random.default_rng(4)
    for alpha, beta, gamma in rng.uniform(-np.pi, np.pi, size=(N, 3)) * [1.0, 0.5, 1.0]:
        expected = Rotation.from_euler("xyz", [gamma, beta, alpha]).as_matrix()  # gamma about fixed X first
        np.testing.assert_allclose(xyz_fixed_to_matrix(alpha, beta, gamma), expected, atol=TOL)
        np.testing.assert_allclose(Rotation.from_euler("ZYX", [alpha, beta, gamma]).as_matrix(), expected, atol=TOL)
        np.testing.assert_allclose(zyx_euler_to_matrix(alpha, beta, gamma), expected, atol=TOL)


def test_eq13_angles_from_a_matrix_match_scipy_away_from_gimbal_lock(rotations: Rotation) -> None:
    for r in rotations:
        gamma, beta, alpha = r.as_euler("xyz")
        if abs(abs(beta) - np.pi / 2) < 1e-3:
            continue
        ours = np.array(matrix_to_xyz_fixed(r.as_matrix()))
        np.testing.assert_allclose(_wrap(ours - [alpha, beta, gamma]), 0.0, atol=1e-10)
        assert matrix_to_zyx_euler(r.as_matrix()) == tuple(ours)


def test_at_gimbal_lock_gamma_is_zero_where_scipy_zeroes_an_angle_too() -> None:
    R = xyz_fixed_to_matrix(0.4, np.pi / 2, -0.9)
    alpha, beta, gamma = matrix_to_xyz_fixed(R)
    assert gamma == 0.0 and beta == pytest.approx(np.pi / 2, abs=1e-12)
    np.testing.assert_allclose(Rotation.from_euler("xyz", [gamma, beta, alpha]).as_matrix(), R, atol=TOL)


def test_rotation_vectors_match_scipy_below_a_half_turn(rotations: Rotation) -> None:
    for r in rotations:
        rv = r.as_rotvec()
        np.testing.assert_allclose(axis_angle_to_matrix(rv), r.as_matrix(), atol=TOL)
        ours = matrix_to_axis_angle(r.as_matrix())
        assert np.linalg.norm(ours) <= np.pi + 1e-12
        if np.linalg.norm(rv) < np.pi - 1e-6:
            np.testing.assert_allclose(ours, rv, atol=1e-10)
        np.testing.assert_allclose(Rotation.from_rotvec(ours).as_matrix(), r.as_matrix(), atol=TOL)


def test_tiny_rotation_vectors_keep_full_precision() -> None:
    for theta in (1e-15, 1e-12, 1e-9, 1e-6):
        v = np.array([0.2, -0.5, 0.84]) / np.linalg.norm([0.2, -0.5, 0.84]) * theta
        np.testing.assert_allclose(axis_angle_to_matrix(v), Rotation.from_rotvec(v).as_matrix(), atol=1e-16)
        if theta > 2e-15:  # below that the angle reads as exactly 0
            np.testing.assert_allclose(matrix_to_axis_angle(axis_angle_to_matrix(v)), v, rtol=1e-6, atol=1e-17)


def test_a_half_turn_keeps_the_project_sign_where_scipy_may_flip_it() -> None:
    # pi about n = (-0.6, 0.8, 0): w = 0, and the component the conversion chose (y, the largest) stays positive.
    n = np.array([-0.6, 0.8, 0.0])
    R = 2.0 * np.outer(n, n) - np.eye(3)
    np.testing.assert_allclose(matrix_to_quat(R), [0.0, -0.6, 0.8, 0.0], atol=TOL)
    np.testing.assert_allclose(matrix_to_axis_angle(R), np.pi * n, atol=TOL)
    np.testing.assert_allclose(Rotation.from_rotvec(matrix_to_axis_angle(R)).as_matrix(), R, atol=TOL)


def test_geodesic_angle_is_scipys_relative_magnitude(rotations: Rotation) -> None:
    others = Rotation.random(len(rotations), random_state=5)
    for a, b in zip(rotations, others):
        expected = (a.inv() * b).magnitude()
        assert rotation_angle_between(a.as_matrix(), b.as_matrix()) == pytest.approx(expected, abs=1e-10)


def test_minimal_rotation_is_scipys_shortest_arc() -> None:
    rng = np.random.default_rng(6)
    for a, b in rng.normal(size=(N, 2, 3)):
        R = minimal_rotation(a, b)
        expected, _ = Rotation.align_vectors(b[None], a[None])
        np.testing.assert_allclose(R, expected.as_matrix(), atol=1e-10)
        np.testing.assert_allclose(R @ a / np.linalg.norm(a), b / np.linalg.norm(b), atol=1e-12)


def test_nearest_rotation_is_scipys_kabsch_solution() -> None:
    rng = np.random.default_rng(7)
    for r in Rotation.random(N, random_state=8):
        M = r.as_matrix() + rng.normal(scale=rng.choice([1e-9, 1e-4, 0.1]), size=(3, 3))
        if rng.uniform() < 0.2:
            M[:, 0] = -M[:, 0]  # a reflection: still projected onto the rotations
        expected, _ = Rotation.align_vectors(M.T, np.eye(3))  # argmin ||M - R||_F
        np.testing.assert_allclose(nearest_rotation(M), expected.as_matrix(), atol=1e-9)


def test_mean_pose_is_scipys_chordal_mean() -> None:
    rng = np.random.default_rng(9)
    base = Rotation.from_rotvec([0.3, -0.2, 1.1])
    rots = Rotation.from_rotvec(rng.normal(scale=0.01, size=(20, 3))) * base
    t = rng.normal(scale=100.0, size=(20, 3))
    mean = mean_pose(np.stack([make_pose(r.as_matrix(), ti) for r, ti in zip(rots, t)]))
    np.testing.assert_allclose(mean[:3, :3], rots.mean().as_matrix(), atol=1e-6)  # chordal L2 vs quaternion mean
    np.testing.assert_allclose(mean[:3, 3], t.mean(axis=0), atol=1e-9)
