"""Quaternion helpers (w, x, y, z) for the ABB driver's tests, on the core's rotation math.

The driver keeps no rotation math of its own beyond its wire convention; the tests build and
compare orientations with :mod:`cellctl.geometry.rotation`, an oracle independent of the fake.
Every quaternion returned is a unit one with w >= 0.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.rotation import (
    axis_angle_to_matrix,
    matrix_to_quat,
    quat_to_matrix,
    rotation_angle_between,
)

Quat = tuple[float, float, float, float]


def _quat(R: NDArray[np.float64]) -> Quat:
    w, x, y, z = (float(c) for c in matrix_to_quat(R))
    return (w, x, y, z)


def to_matrix(q: Sequence[float]) -> NDArray[np.float64]:
    """3x3 rotation matrix of a quaternion."""
    return quat_to_matrix(q)


def normalise(q: Sequence[float]) -> Quat:
    """The unit quaternion (w >= 0) of ``q``'s rotation."""
    return _quat(quat_to_matrix(q))


def multiply(a: Sequence[float], b: Sequence[float]) -> Quat:
    """The rotation ``b`` first, then ``a``."""
    return _quat(quat_to_matrix(a) @ quat_to_matrix(b))


def from_rotation_vector(v: Sequence[float]) -> Quat:
    """The rotation of a rotation vector (axis times angle, rad)."""
    return _quat(axis_angle_to_matrix(np.asarray(v, dtype=float)))


def angle_between(a: Sequence[float], b: Sequence[float]) -> float:
    """Rotation angle (rad, 0..pi) that takes orientation ``a`` to orientation ``b``."""
    return rotation_angle_between(quat_to_matrix(a), quat_to_matrix(b))
