"""Rigid offsets within the workpiece plane (the T' of paper section 4.2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellctl.geometry.pose import Pose, make_pose
from cellctl.geometry.rotation import rot_z


@dataclass(frozen=True)
class PlanarOffset:
    """The true workpiece frame relative to the estimated one, within the wall plane.

    ``dx_mm``, ``dy_mm`` along the workpiece frame's x (right) and y (down) axes and ``dtheta_rad``
    about its z axis (into the wall; positive turns x towards y, as the image's u turns to v).
    """

    dx_mm: float
    dy_mm: float
    dtheta_rad: float

    def __post_init__(self) -> None:
        if not np.all(np.isfinite([self.dx_mm, self.dy_mm, self.dtheta_rad])):
            raise ValueError(f"planar offset must be finite, got {self}")

    def as_pose(self) -> Pose:
        """T' as a 4x4 pose: ``p_T1 = T' @ p_T2``."""
        return make_pose(rot_z(self.dtheta_rad), [self.dx_mm, self.dy_mm, 0.0])


def rot2(angle_rad: float) -> np.ndarray:
    """The 2 x 2 rotation turning x towards y by ``angle_rad`` (in-plane directions, image or wall)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s], [s, c]])


def wrap_angle(angle_rad: float) -> float:
    """``angle_rad`` in [-pi, pi)."""
    return float((angle_rad + np.pi) % (2.0 * np.pi) - np.pi)
