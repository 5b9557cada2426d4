"""Rigid transforms as 4x4 homogeneous matrices.

Naming: ``T_a_b`` is frame b expressed in frame a, so ``p_a = T_a_b @ p_b`` and
``T_a_c = T_a_b @ T_b_c``. Translations are in millimetres.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.geometry.rotation import (
    axis_angle_to_matrix,
    is_rotation,
    matrix_to_axis_angle,
    matrix_to_xyz_fixed,
    nearest_rotation,
    xyz_fixed_to_matrix,
)

Pose = NDArray[np.float64]


def make_pose(R: ArrayLike, t: ArrayLike) -> Pose:
    """4x4 pose from a 3x3 rotation and a 3-vector translation (mm)."""
    Rm = np.asarray(R, dtype=float)
    tv = np.asarray(t, dtype=float).reshape(-1)
    if Rm.shape != (3, 3) or tv.shape != (3,):
        raise ValueError(f"make_pose needs R 3x3 and t 3-vector, got {Rm.shape} and {tv.shape}")
    T = np.eye(4)
    T[:3, :3] = Rm
    T[:3, 3] = tv
    return T


_BOTTOM_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_BOTTOM_RTOL = 1e-5 * _BOTTOM_ROW  # np.allclose's default rtol, relative to the row it compares with


def check_pose(T: ArrayLike, name: str = "pose", tol: float = 1e-6) -> Pose:
    """Return ``T`` as a float 4x4 array after checking it is a finite rigid transform.

    Raises ValueError naming ``name`` when it is not (wrong shape, non-finite values, a rotation
    part that is not orthonormal, or a bottom row other than 0 0 0 1).
    """
    M = np.asarray(T, dtype=float)
    if M.shape != (4, 4):
        raise ValueError(f"{name}: expected a 4x4 homogeneous matrix, got shape {M.shape}")
    if not np.isfinite(M).all():
        raise ValueError(f"{name}: contains NaN or infinite values")
    if not (np.abs(M[3] - _BOTTOM_ROW) <= tol + _BOTTOM_RTOL).all():  # np.allclose's test, without its overhead
        raise ValueError(f"{name}: bottom row must be [0, 0, 0, 1], got {M[3].tolist()}")
    if not is_rotation(M[:3, :3], tol=tol):
        raise ValueError(f"{name}: rotation part is not orthonormal with det +1 (re-orthonormalise it)")
    return M


def invert_pose(T: ArrayLike) -> Pose:
    """Inverse of a rigid transform, using the transpose of its rotation."""
    M = np.asarray(T, dtype=float)
    R = M[:3, :3]
    return make_pose(R.T, -R.T @ M[:3, 3])


def compose(*poses: ArrayLike) -> Pose:
    """Product of poses left to right: ``compose(T_a_b, T_b_c) == T_a_c``."""
    out = np.eye(4)
    for T in poses:
        out = out @ np.asarray(T, dtype=float)
    return out


def apply_pose(T: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Transform points (shape (3,) or (N, 3)) by ``T``: ``p_a = T_a_b @ p_b``."""
    M = np.asarray(T, dtype=float)
    P = np.asarray(points, dtype=float)
    out = P @ M[:3, :3].T + M[:3, 3]
    return out


def rotate_vectors(T: ArrayLike, vectors: ArrayLike) -> NDArray[np.float64]:
    """Rotate directions (shape (3,) or (N, 3)) by the rotation part of ``T`` only."""
    M = np.asarray(T, dtype=float)
    return np.asarray(vectors, dtype=float) @ M[:3, :3].T


def translation(T: ArrayLike) -> NDArray[np.float64]:
    """The translation part of a pose (mm)."""
    return np.asarray(T, dtype=float)[:3, 3].copy()


def rotation(T: ArrayLike) -> NDArray[np.float64]:
    """The rotation part of a pose."""
    return np.asarray(T, dtype=float)[:3, :3].copy()


def pose_from_xyz_fixed(t: ArrayLike, alpha: float, beta: float, gamma: float) -> Pose:
    """Pose from a translation and the paper's XYZ fixed angles (eq. 13), radians."""
    return make_pose(xyz_fixed_to_matrix(alpha, beta, gamma), t)


def pose_from_xyz_fixed_deg(t: ArrayLike, rx_ry_rz_deg: ArrayLike) -> Pose:
    """Pose from a translation and XYZ fixed angles given as (rx, ry, rz) in degrees, as configs give them (eq. 13)."""
    rx, ry, rz = np.deg2rad(np.asarray(rx_ry_rz_deg, dtype=float))
    return pose_from_xyz_fixed(t, rz, ry, rx)


def pose_to_xyz_fixed(T: ArrayLike) -> tuple[NDArray[np.float64], tuple[float, float, float]]:
    """Translation and (alpha, beta, gamma) XYZ fixed angles of a pose (eq. 13), radians."""
    return translation(T), matrix_to_xyz_fixed(rotation(T))


def pose_from_rotvec(t: ArrayLike, rotvec: ArrayLike) -> Pose:
    """Pose from a translation and a rotation vector (axis times angle, radians)."""
    return make_pose(axis_angle_to_matrix(rotvec), t)


def pose_error(T_ref: ArrayLike, T: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Deviation of ``T`` from ``T_ref`` expressed in the frame of ``T_ref``.

    Returns (dt, drotvec): the translation (mm) and rotation vector (rad) of ``inv(T_ref) @ T``.
    """
    E = invert_pose(T_ref) @ np.asarray(T, dtype=float)
    return translation(E), matrix_to_axis_angle(rotation(E))


def mean_pose(poses: ArrayLike) -> Pose:
    """The mean of nearby poses: mean translation, and the rotation nearest the summed rotations.

    Meant for estimates of one frame that differ by small errors (chordal L2 mean on SO(3)).
    """
    P = np.asarray(poses, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or P.shape[0] == 0:
        raise ValueError(f"mean_pose needs (N, 4, 4) poses with N >= 1, got shape {P.shape}")
    return make_pose(nearest_rotation(P[:, :3, :3].sum(axis=0)), P[:, :3, 3].mean(axis=0))


def pose_in_plane(T_B_F: ArrayLike, offset_xy_mm: ArrayLike, angle_rad: float = 0.0) -> Pose:
    """A frame lying in the x-y plane of frame F, shifted by ``offset_xy_mm`` and turned by ``angle_rad`` about F's z.

    E.g. a checkerboard stuck on the car-body wall: F is the workpiece frame T, the board's origin
    (first inner corner) sits at ``offset_xy_mm`` in T.
    """
    T = check_pose(T_B_F, "T_B_F")
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    local = np.eye(4)
    local[:2, :2] = [[c, -s], [s, c]]
    local[:2, 3] = np.asarray(offset_xy_mm, dtype=float)[:2]
    return T @ local
