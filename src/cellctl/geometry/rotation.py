"""Rotations: elementary, quaternion (ABB order w, x, y, z), XYZ fixed angles (eq. 13), axis-angle.

Radians throughout; pure functions over numpy arrays. Conventions: quaternions with w >= 0;
rotation vectors with the angle in [0, pi], taken from that quaternion; eq. 13's inverse puts
gamma = 0 at gimbal lock. ``tests/unit/test_geometry_scipy.py`` checks every function against
``scipy.spatial.transform.Rotation``; the conversions stay written out here because scipy rounds
differently, and the calibration figures follow the last bit of every robot pose (scipy in their
place moved the laser calibration's figures by up to 1e-5 relative).

- Paper's XYZ fixed angles (eq. 13): ``R = Rz(alpha) @ Ry(beta) @ Rx(gamma)``.
- RAPID's ``OrientZYX(z, y, x)`` is the same matrix ``Rz(z) @ Ry(y) @ Rx(x)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Matrix3 = NDArray[np.float64]
Vector = NDArray[np.float64]


def rot_x(angle: float) -> Matrix3:
    """Rotation about the X axis by ``angle`` (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> Matrix3:
    """Rotation about the Y axis by ``angle`` (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> Matrix3:
    """Rotation about the Z axis by ``angle`` (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def skew(v: ArrayLike) -> Matrix3:
    """The cross-product matrix [v]x of a 3-vector: ``skew(v) @ u == cross(v, u)``."""
    x, y, z = (float(c) for c in np.asarray(v, dtype=float).reshape(3))
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


_I3 = np.eye(3)
_I3.flags.writeable = False
_RTOL_I3 = 1e-5 * _I3


def is_rotation(R: ArrayLike, tol: float = 1e-9) -> bool:
    """True if ``R`` is a finite 3x3 orthonormal matrix with determinant +1 within ``tol``."""
    M = np.asarray(R, dtype=float)
    if M.shape != (3, 3) or not np.isfinite(M).all():
        return False
    # np.allclose(M.T @ M, I, atol=tol) spelled out (its rtol 1e-5 applies on the diagonal): a third of its time.
    return bool((np.abs(M.T @ M - _I3) <= tol + _RTOL_I3).all() and abs(np.linalg.det(M) - 1.0) < tol)


def nearest_rotation(M: ArrayLike) -> Matrix3:
    """The rotation nearest ``M`` in the Frobenius norm: SVD projection onto SO(3), reflections turned.

    Re-orthonormalises rounded matrices such as the paper's printed hand-eye result (eq. 18).
    """
    A = np.asarray(M, dtype=float)
    if A.shape != (3, 3) or not np.all(np.isfinite(A)):
        raise ValueError(f"nearest_rotation needs a finite 3x3 matrix, got shape {A.shape}")
    U, S, Vt = np.linalg.svd(A)
    if S[-1] < 1e-9 * max(S[0], 1e-300):
        raise ValueError(f"matrix is singular (singular values {S}); it is not a rounded rotation")
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def quat_to_matrix(q: ArrayLike) -> Matrix3:
    """Rotation matrix of a quaternion in ABB order (w, x, y, z) = (q1, q2, q3, q4), normalised first."""
    v = np.asarray(q, dtype=float)
    if v.shape != (4,) or not np.all(np.isfinite(v)):
        raise ValueError(f"quaternion must be 4 finite numbers (w, x, y, z), got {q!r}")
    n = np.linalg.norm(v)
    if n < 1e-12:
        raise ValueError("quaternion has zero length; expected a unit quaternion (w, x, y, z)")
    w, x, y, z = v / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(R: ArrayLike) -> Vector:
    """Unit quaternion (w, x, y, z) of a rotation matrix, w >= 0 (Shepperd's method).

    At w = 0 (a half turn) the largest of x, y, z is positive.
    """
    M = np.asarray(R, dtype=float)
    if M.shape != (3, 3) or not np.all(np.isfinite(M)):
        raise ValueError(f"rotation must be a finite 3x3 matrix, got shape {M.shape}")
    tr = np.trace(M)
    k = int(np.argmax([tr, *np.diag(M)]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = np.array([0.25 * s, (M[2, 1] - M[1, 2]) / s, (M[0, 2] - M[2, 0]) / s, (M[1, 0] - M[0, 1]) / s])
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + M[0, 0] - M[1, 1] - M[2, 2])
        q = np.array([(M[2, 1] - M[1, 2]) / s, 0.25 * s, (M[0, 1] + M[1, 0]) / s, (M[0, 2] + M[2, 0]) / s])
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 - M[0, 0] + M[1, 1] - M[2, 2])
        q = np.array([(M[0, 2] - M[2, 0]) / s, (M[0, 1] + M[1, 0]) / s, 0.25 * s, (M[1, 2] + M[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 - M[0, 0] - M[1, 1] + M[2, 2])
        q = np.array([(M[1, 0] - M[0, 1]) / s, (M[0, 2] + M[2, 0]) / s, (M[1, 2] + M[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def xyz_fixed_to_matrix(alpha: float, beta: float, gamma: float) -> Matrix3:
    """Paper eq. 13: gamma about fixed X, then beta about fixed Y, then alpha about fixed Z (rad).

    ``R = Rz(alpha) @ Ry(beta) @ Rx(gamma)``.
    """
    return rot_z(alpha) @ rot_y(beta) @ rot_x(gamma)


def matrix_to_xyz_fixed(R: ArrayLike) -> tuple[float, float, float]:
    """(alpha, beta, gamma) with ``R = Rz(alpha) @ Ry(beta) @ Rx(gamma)`` (eq. 13), beta in [-pi/2, pi/2].

    At gimbal lock (beta = +-pi/2) only alpha -+ gamma is determined: gamma is 0 there, and
    alpha is solved from what remains, so the triple rebuilds ``R`` to rounding at and near the lock.
    """
    M = np.asarray(R, dtype=float)
    if not is_rotation(M, tol=1e-6):
        raise ValueError("matrix_to_xyz_fixed needs a rotation matrix (orthonormal, det +1)")
    beta = float(np.arctan2(-M[2, 0], np.hypot(M[0, 0], M[1, 0])))
    # below 1e-14 gamma is left 0: what it would have rotated is at most cos(beta) (a rounding-sized 1e-12 lock
    # left out a gamma of pi/2 to 1e-12); above, arctan2 of such small terms is coarse but rebuilds R to rounding
    gamma = float(np.arctan2(M[2, 1], M[2, 2])) if np.cos(beta) > 1e-14 else 0.0
    Mz = M @ rot_x(gamma).T @ rot_y(beta).T  # Rz(alpha), well conditioned even at the lock
    alpha = float(np.arctan2(Mz[1, 0], Mz[0, 0]))
    return alpha, beta, gamma


def zyx_euler_to_matrix(z: float, y: float, x: float) -> Matrix3:
    """RAPID's ``OrientZYX(z, y, x)`` (radians here): ``Rz(z) @ Ry(y) @ Rx(x)``."""
    return xyz_fixed_to_matrix(z, y, x)


def matrix_to_zyx_euler(R: ArrayLike) -> tuple[float, float, float]:
    """RAPID's ``EulerZYX`` triple (z, y, x) in radians; the same matrix as the XYZ fixed angles."""
    return matrix_to_xyz_fixed(R)


def axis_angle_to_matrix(rotvec: ArrayLike) -> Matrix3:
    """Rotation of a rotation vector (unit axis times angle, rad), Rodrigues' formula."""
    v = np.asarray(rotvec, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"rotation vector must be 3 finite numbers, got {rotvec!r}")
    theta = float(np.linalg.norm(v))
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    if theta < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K  # second-order series: full precision for tiny angles
    K /= theta
    return np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)


def matrix_to_axis_angle(R: ArrayLike) -> Vector:
    """Rotation vector (axis times angle, angle in [0, pi]) of a rotation matrix, from its w >= 0 quaternion."""
    w, x, y, z = matrix_to_quat(R)
    s = float(np.linalg.norm([x, y, z]))
    if s < 1e-15:
        return np.zeros(3)
    angle = 2.0 * np.arctan2(s, w)
    return np.array([x, y, z]) / s * angle


def rotation_angle_between(Ra: ArrayLike, Rb: ArrayLike) -> float:
    """Angle (rad) of the relative rotation ``Ra^T @ Rb``: the geodesic distance on SO(3)."""
    return float(np.linalg.norm(matrix_to_axis_angle(np.asarray(Ra).T @ np.asarray(Rb))))


def angle_between_vectors(a: ArrayLike, b: ArrayLike) -> float:
    """Angle (rad) between two 3-vectors, accurate for tiny and near-pi angles."""
    u = np.asarray(a, dtype=float)
    v = np.asarray(b, dtype=float)
    return float(np.arctan2(np.linalg.norm(np.cross(u, v)), np.dot(u, v)))


def minimal_rotation(a: ArrayLike, b: ArrayLike) -> Matrix3:
    """The smallest rotation turning direction ``a`` onto ``b`` (no spin about them).

    Antiparallel inputs: pi about the axis ``a x e_k``, e_k the base axis least along ``a``.
    """
    u = np.asarray(a, dtype=float)
    v = np.asarray(b, dtype=float)
    nu, nv = np.linalg.norm(u), np.linalg.norm(v)
    if nu < 1e-12 or nv < 1e-12:
        raise ValueError("minimal_rotation needs two non-zero directions")
    u, v = u / nu, v / nv
    axis = np.cross(u, v)
    s = np.linalg.norm(axis)
    angle = np.arctan2(s, np.dot(u, v))
    if s < 1e-15:
        if angle < 1.0:
            return np.eye(3)
        perp = np.cross(u, np.eye(3)[int(np.argmin(np.abs(u)))])
        return axis_angle_to_matrix(perp / np.linalg.norm(perp) * np.pi)
    return axis_angle_to_matrix(axis / s * angle)
