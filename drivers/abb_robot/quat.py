"""Small quaternion helpers (w, x, y, z, unit norm) for the driver and its fake.

The driver may import only ``cellctl.ports`` from the core, so it carries these few pure
functions itself. All take and return plain tuples or numpy arrays; none keeps state.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

Quat = tuple[float, float, float, float]


def normalise(q: Sequence[float]) -> Quat:
    """The unit quaternion with w >= 0 (q and -q are the same rotation)."""
    a = np.asarray(q, dtype=float)
    n = float(np.linalg.norm(a))
    if a.shape != (4,) or not math.isfinite(n) or n < 1e-12:
        raise ValueError(f"not a usable quaternion (w, x, y, z): {tuple(q)!r}")
    a = a / n
    if a[0] < 0:
        a = -a
    return (float(a[0]), float(a[1]), float(a[2]), float(a[3]))


def to_matrix(q: Sequence[float]) -> NDArray[np.float64]:
    """3x3 rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = normalise(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def from_matrix(R: NDArray[np.float64]) -> Quat:
    """Unit quaternion (w >= 0) of a 3x3 rotation matrix (Shepperd's method)."""
    m = np.asarray(R, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    return normalise(q)


def multiply(a: Sequence[float], b: Sequence[float]) -> Quat:
    """Hamilton product a * b (rotation b first, then a)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def angle_between(a: Sequence[float], b: Sequence[float]) -> float:
    """Rotation angle (rad, 0..pi) that takes orientation a to orientation b."""
    ua, ub = normalise(a), normalise(b)
    d = abs(sum(x * y for x, y in zip(ua, ub)))
    return 2.0 * math.acos(min(1.0, d))


def slerp(a: Sequence[float], b: Sequence[float], t: float) -> Quat:
    """Spherical interpolation from a (t = 0) to b (t = 1) along the shorter arc."""
    ua = np.asarray(normalise(a))
    ub = np.asarray(normalise(b))
    d = float(np.dot(ua, ub))
    if d < 0:
        ub, d = -ub, -d
    if d > 0.9995:
        return normalise(ua + t * (ub - ua))
    theta = math.acos(d)
    s = math.sin(theta)
    out = (math.sin((1 - t) * theta) / s) * ua + (math.sin(t * theta) / s) * ub
    return normalise(out)


def from_rotation_vector(v: Sequence[float]) -> Quat:
    """Quaternion of a rotation vector (axis times angle, rad)."""
    angle = math.sqrt(sum(c * c for c in v))
    if angle < 1e-15:
        return (1.0, 0.0, 0.0, 0.0)
    s = math.sin(angle / 2) / angle
    return normalise((math.cos(angle / 2), v[0] * s, v[1] * s, v[2] * s))


def to_euler_zyx_deg(q: Sequence[float]) -> tuple[float, float, float]:
    """ABB's Euler angles (EulerZYX: rx, ry, rz in degrees) of a quaternion, R = Rz Ry Rx."""
    R = to_matrix(q)
    ry = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    rx = math.atan2(R[2, 1], R[2, 2])
    rz = math.atan2(R[1, 0], R[0, 0])
    return (math.degrees(rx), math.degrees(ry), math.degrees(rz))
