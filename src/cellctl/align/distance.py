"""Distance correction to the working distance (paper eq. 14)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.align.errors import AlignmentError
from cellctl.geometry.plane import PlaneFit
from cellctl.geometry.pose import Pose, make_pose


@dataclass(frozen=True)
class DistanceCorrection:
    """The flange move that brings the camera's optical centre to the working distance.

    Attributes:
        distance_before_mm: optical centre to wall along the normal, before the move.
        delta_d_mm: distance_before - working distance; positive means move towards the wall.
        delta_H_mm: the move in the flange frame, ``R_H_C @ (0, 0, delta_d)`` (eq. 14).
        T_B_H: the corrected flange pose.
    """

    distance_before_mm: float
    delta_d_mm: float
    delta_H_mm: NDArray[np.float64]
    T_B_H: Pose


def camera_distance_to_plane(T_B_H: ArrayLike, T_H_C: ArrayLike, plane: PlaneFit) -> float:
    """Distance (mm) from the camera's optical centre to the plane, positive in front of the wall.

    The plane's normal must point into the wall.
    """
    p_C = (np.asarray(T_B_H, dtype=float) @ np.asarray(T_H_C, dtype=float))[:3, 3]
    return float(plane.offset - plane.normal @ p_C)


def correct_distance(T_B_H: ArrayLike, T_H_C: ArrayLike, plane: PlaneFit, working_distance_mm: float) -> DistanceCorrection:
    """Eq. 14: decompose the distance error along the camera's z axis into the flange frame.

    Expects the camera's z axis already along the plane normal (after the orientation step); the
    move then changes the distance by exactly ``delta_d``.
    """
    if not np.isfinite(working_distance_mm) or working_distance_mm <= 0:
        raise AlignmentError(f"working distance must be a positive number of mm, got {working_distance_mm}")
    TH = np.asarray(T_B_H, dtype=float)
    THC = np.asarray(T_H_C, dtype=float)
    before = camera_distance_to_plane(TH, THC, plane)
    if before <= 0:
        raise AlignmentError(
            f"the camera's optical centre is {-before:.1f} mm behind the fitted wall; the plane or the "
            "hand-eye transform is wrong"
        )
    delta_d = before - working_distance_mm
    delta_H = THC[:3, :3] @ np.array([0.0, 0.0, delta_d])  # eq. 14
    p_new = TH[:3, 3] + TH[:3, :3] @ delta_H
    return DistanceCorrection(before, float(delta_d), delta_H, make_pose(TH[:3, :3], p_new))
