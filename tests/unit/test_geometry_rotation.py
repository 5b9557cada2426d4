"""Rotation conversions: round trips to 1e-12, including at and near gimbal lock."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cellctl.geometry import (
    axis_angle_to_matrix,
    is_rotation,
    matrix_to_axis_angle,
    matrix_to_quat,
    matrix_to_xyz_fixed,
    matrix_to_zyx_euler,
    minimal_rotation,
    nearest_rotation,
    quat_to_matrix,
    rot_x,
    rot_y,
    rot_z,
    xyz_fixed_to_matrix,
    zyx_euler_to_matrix,
)

TOL = 1e-12

unit = st.floats(-1.0, 1.0, allow_nan=False)
angle = st.floats(-np.pi, np.pi, allow_nan=False)


@st.composite
def rotations(draw: st.DrawFn) -> np.ndarray:
    """Uniform-ish random rotations from random (non-zero) quaternions."""
    q = np.array([draw(unit) for _ in range(4)])
    if np.linalg.norm(q) < 1e-3:
        q = np.array([1.0, 0.0, 0.0, 0.0])
    return quat_to_matrix(q)


@st.composite
def near_gimbal_lock(draw: st.DrawFn) -> np.ndarray:
    """Rotations with beta at +-pi/2 exactly or within 1e-13 .. 1e-3 of it."""
    sign = draw(st.sampled_from([-1.0, 1.0]))
    offset = draw(st.sampled_from([0.0, 1e-13, 1e-10, 1e-7, 1e-5, 1e-3])) * draw(st.sampled_from([-1.0, 1.0]))
    beta = sign * (np.pi / 2 - abs(offset))
    return xyz_fixed_to_matrix(draw(angle), beta, draw(angle))


def test_elementary_rotations_follow_the_right_hand_rule() -> None:
    np.testing.assert_allclose(rot_z(np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=TOL)
    np.testing.assert_allclose(rot_x(np.pi / 2) @ [0, 1, 0], [0, 0, 1], atol=TOL)
    np.testing.assert_allclose(rot_y(np.pi / 2) @ [0, 0, 1], [1, 0, 0], atol=TOL)


def test_xyz_fixed_is_the_papers_eq13_matrix() -> None:
    a, b, g = 0.3, -0.7, 1.1
    ca, sa, cb, sb, cg, sg = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(g), np.sin(g)
    eq13 = np.array(
        [
            [ca * cb, ca * sb * sg - sa * cg, ca * sb * cg + sa * sg],
            [sa * cb, sa * sb * sg + ca * cg, sa * sb * cg - ca * sg],
            [-sb, cb * sg, cb * cg],
        ]
    )
    np.testing.assert_allclose(xyz_fixed_to_matrix(a, b, g), eq13, atol=TOL)


def test_quaternion_is_w_first_as_abb_orders_it() -> None:
    # 90 deg about z: w = cos 45, z = sin 45.
    q = matrix_to_quat(rot_z(np.pi / 2))
    np.testing.assert_allclose(q, [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=TOL)


@settings(max_examples=400, deadline=None)
@given(rotations())
def test_quaternion_round_trip(R: np.ndarray) -> None:
    q = matrix_to_quat(R)
    assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < TOL
    np.testing.assert_allclose(quat_to_matrix(q), R, atol=TOL)


# cos(beta) = 1.0e-12 with gamma pi/2: a lock taken at 1e-12 left gamma out and rebuilt R 1.00015e-12 off
# (hypothesis drew it for 2 of 600 seeds); every run checks it
NEAR_LOCK = quat_to_matrix(np.array([1e-12, 1.0, 0.0, 1.0]))


@settings(max_examples=400, deadline=None)
@given(rotations())
@example(NEAR_LOCK)
def test_xyz_fixed_round_trip(R: np.ndarray) -> None:
    alpha, beta, gamma = matrix_to_xyz_fixed(R)
    assert -np.pi / 2 <= beta <= np.pi / 2
    np.testing.assert_allclose(xyz_fixed_to_matrix(alpha, beta, gamma), R, atol=TOL)


@settings(max_examples=400, deadline=None)
@given(near_gimbal_lock())
def test_xyz_fixed_round_trip_at_and_near_gimbal_lock(R: np.ndarray) -> None:
    alpha, beta, gamma = matrix_to_xyz_fixed(R)
    assert all(np.isfinite([alpha, beta, gamma]))
    np.testing.assert_allclose(xyz_fixed_to_matrix(alpha, beta, gamma), R, atol=TOL)


def test_exact_gimbal_lock_returns_an_equivalent_triple_with_gamma_zero() -> None:
    R = xyz_fixed_to_matrix(0.4, np.pi / 2, -0.9)
    alpha, beta, gamma = matrix_to_xyz_fixed(R)
    assert beta == pytest.approx(np.pi / 2, abs=1e-12)
    assert gamma == 0.0
    np.testing.assert_allclose(xyz_fixed_to_matrix(alpha, beta, gamma), R, atol=TOL)


@settings(max_examples=300, deadline=None)
@given(rotations())
@example(NEAR_LOCK)
def test_rapid_zyx_euler_round_trip_and_order(R: np.ndarray) -> None:
    z, y, x = matrix_to_zyx_euler(R)
    np.testing.assert_allclose(zyx_euler_to_matrix(z, y, x), R, atol=TOL)
    np.testing.assert_allclose(zyx_euler_to_matrix(z, y, x), rot_z(z) @ rot_y(y) @ rot_x(x), atol=TOL)


@settings(max_examples=400, deadline=None)
@given(rotations())
def test_axis_angle_round_trip(R: np.ndarray) -> None:
    v = matrix_to_axis_angle(R)
    assert np.linalg.norm(v) <= np.pi + 1e-12
    np.testing.assert_allclose(axis_angle_to_matrix(v), R, atol=TOL)


@pytest.mark.parametrize("theta", [0.0, 1e-14, 1e-9, 1e-5, np.pi - 1e-9, np.pi])
def test_axis_angle_small_and_near_pi(theta: float) -> None:
    axis = np.array([0.2, -0.5, 0.84])
    axis /= np.linalg.norm(axis)
    R = axis_angle_to_matrix(axis * theta)
    np.testing.assert_allclose(axis_angle_to_matrix(matrix_to_axis_angle(R)), R, atol=TOL)


def test_nearest_rotation_repairs_the_papers_rounded_hand_eye() -> None:
    printed = np.array([[0.007, -0.036, -0.999], [1, 0.0074, 0.006], [0.007, -0.998, 0.036]])
    assert not is_rotation(printed)
    R = nearest_rotation(printed)
    assert is_rotation(R, tol=1e-12)
    assert np.max(np.abs(R - printed)) < 2e-3


@settings(max_examples=200, deadline=None)
@given(rotations(), st.floats(1e-6, 1e-2))
def test_nearest_rotation_is_identity_on_rotations_and_undoes_small_noise(R: np.ndarray, eps: float) -> None:
    np.testing.assert_allclose(nearest_rotation(R), R, atol=TOL)
    noisy = R + eps * np.sin(np.arange(9).reshape(3, 3) + 1.0)
    assert is_rotation(nearest_rotation(noisy), tol=1e-12)


def test_nearest_rotation_refuses_singular_input() -> None:
    with pytest.raises(ValueError, match="singular"):
        nearest_rotation(np.zeros((3, 3)))


@settings(max_examples=300, deadline=None)
@given(rotations(), rotations())
def test_minimal_rotation_maps_a_onto_b_without_spin(Ra: np.ndarray, Rb: np.ndarray) -> None:
    a, b = Ra[:, 0], Rb[:, 0]
    M = minimal_rotation(a, b)
    np.testing.assert_allclose(M @ a, b, atol=1e-12)
    axis = matrix_to_axis_angle(M)
    # The rotation axis is perpendicular to both a and b: no spin about either.
    if np.linalg.norm(axis) > 1e-9:
        assert abs(np.dot(axis / np.linalg.norm(axis), a)) < 1e-9


def test_minimal_rotation_antiparallel() -> None:
    M = minimal_rotation([0, 0, 1], [0, 0, -1])
    np.testing.assert_allclose(M @ [0, 0, 1], [0, 0, -1], atol=TOL)
    assert is_rotation(M)


@pytest.mark.parametrize("bad", [[np.nan, 0, 0, 1], [0, 0, 0, 0], [1, 2, 3]])
def test_bad_quaternions_are_refused(bad: list[float]) -> None:
    with pytest.raises(ValueError, match="quaternion"):
        quat_to_matrix(bad)


@settings(max_examples=300, deadline=None)
@given(rotations(), st.floats(-12.0, -3.0), st.floats(-10.0, -5.0), st.integers(0, 2**32 - 1))
def test_is_rotation_is_numpys_allclose_on_the_gram_matrix_and_det_one(
    R: np.ndarray, log_noise: float, log_tol: float, seed: int
) -> None:
    """The hand-spelled test agrees with np.allclose(R.T R, I, atol=tol) and |det R - 1| < tol on either side of tol."""
    M = R + 10.0**log_noise * np.random.default_rng(seed).standard_normal((3, 3))
    tol = 10.0**log_tol
    expected = bool(np.allclose(M.T @ M, np.eye(3), atol=tol) and abs(np.linalg.det(M) - 1.0) < tol)
    assert is_rotation(M, tol=tol) is expected
