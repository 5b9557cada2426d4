"""SE(3) poses and ABB robtargets."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellctl.geometry import (
    RobTarget,
    apply_pose,
    check_pose,
    compose,
    invert_pose,
    make_pose,
    pose_error,
    pose_from_xyz_fixed,
    pose_to_robtarget,
    pose_to_xyz_fixed,
    quat_to_matrix,
    robtarget_to_pose,
)

coord = st.floats(-5000, 5000, allow_nan=False)
unit = st.floats(-1, 1, allow_nan=False)


@st.composite
def poses(draw: st.DrawFn) -> np.ndarray:
    q = np.array([draw(unit) for _ in range(4)])
    if np.linalg.norm(q) < 1e-3:
        q = np.array([1.0, 0, 0, 0])
    return make_pose(quat_to_matrix(q), [draw(coord) for _ in range(3)])


@settings(max_examples=200, deadline=None)
@given(poses(), poses())
def test_compose_invert_apply(T_a_b: np.ndarray, T_b_c: np.ndarray) -> None:
    T_a_c = compose(T_a_b, T_b_c)
    p_c = np.array([[1.0, 2.0, 3.0], [-40.0, 5.0, 600.0]])
    np.testing.assert_allclose(apply_pose(T_a_c, p_c), apply_pose(T_a_b, apply_pose(T_b_c, p_c)), atol=1e-9)
    np.testing.assert_allclose(compose(T_a_b, invert_pose(T_a_b)), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(invert_pose(T_a_b), np.linalg.inv(T_a_b), atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(poses())
def test_robtarget_round_trip(T: np.ndarray) -> None:
    rt = pose_to_robtarget(T, robconf=(0, -1, 2, 1))
    np.testing.assert_allclose(robtarget_to_pose(rt), T, atol=1e-12 * max(1.0, np.abs(T).max()))
    assert rt.robconf == (0, -1, 2, 1)
    assert rt.rot[0] >= 0


@settings(max_examples=200, deadline=None)
@given(poses())
def test_pose_xyz_fixed_round_trip(T: np.ndarray) -> None:
    t, (a, b, g) = pose_to_xyz_fixed(T)
    np.testing.assert_allclose(pose_from_xyz_fixed(t, a, b, g), T, atol=1e-9)


def test_robtarget_rapid_literal() -> None:
    rt = RobTarget((1200.5, -3.25, 800.0), (1.0, 0.0, 0.0, 0.0), (0, 0, -1, 0))
    assert rt.to_rapid() == (
        "[[1200.500,-3.250,800.000],[1.0000000,0.0000000,0.0000000,0.0000000],[0,0,-1,0],"
        "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]"
    )


def test_robtarget_refuses_non_unit_quaternion() -> None:
    with pytest.raises(ValueError, match="unit quaternion"):
        RobTarget((0, 0, 0), (0.9, 0, 0, 0))


def test_check_pose_names_the_problem() -> None:
    bad = np.eye(4)
    bad[:3, :3] *= 2
    with pytest.raises(ValueError, match="T_H_C: rotation part"):
        check_pose(bad, "T_H_C")
    with pytest.raises(ValueError, match="NaN"):
        check_pose(np.full((4, 4), np.nan), "x")
    with pytest.raises(ValueError, match="4x4"):
        check_pose(np.eye(3), "x")
    for off, ok in ((0.9e-6, True), (1.1e-6, False)):  # the bottom row within tol (1e-6), as np.allclose judges it
        T = np.eye(4)
        T[3, 0] = off
        assert (np.allclose(T[3], [0, 0, 0, 1], atol=1e-6)) is ok
        if ok:
            check_pose(T, "x")
        else:
            with pytest.raises(ValueError, match="x: bottom row"):
                check_pose(T, "x")


def test_pose_error_in_reference_frame() -> None:
    T_ref = pose_from_xyz_fixed([100, 0, 0], np.pi / 2, 0, 0)
    T = T_ref @ make_pose(np.eye(3), [1.0, 0, 0])
    dt, dr = pose_error(T_ref, T)
    np.testing.assert_allclose(dt, [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(dr, 0, atol=1e-12)
