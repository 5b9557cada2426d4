"""Laser alignment, paper section 3: spots to points, wall plane, flange orientation and distance.

:func:`compute_alignment` runs the whole step on measured data; the pieces are importable alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.align.distance import DistanceCorrection, camera_distance_to_plane, correct_distance
from cellctl.align.errors import AlignmentError
from cellctl.align.laser_points import (
    flange_pose_for_spot,
    laser_origins,
    laser_points,
    plan_spot_poses,
)
from cellctl.align.orientation import FlangeOrientation, solve_orientation_lm, solve_orientation_minimal
from cellctl.align.wall import (
    NormalUncertainty,
    RejectedSpot,
    WallPlane,
    fit_wall_plane,
    offset_at_rest,
    orient_normal_into_wall,
    predict_normal_uncertainty,
)
from cellctl.geometry.pose import Pose, check_pose, make_pose
from cellctl.geometry.rotation import angle_between_vectors, rotation_angle_between

__all__ = [
    "AlignmentError",
    "AlignmentResult",
    "DistanceCorrection",
    "FlangeOrientation",
    "NormalUncertainty",
    "RejectedSpot",
    "WallPlane",
    "camera_distance_to_plane",
    "compute_alignment",
    "correct_distance",
    "fit_wall_plane",
    "flange_pose_for_spot",
    "laser_origins",
    "laser_points",
    "offset_at_rest",
    "orient_normal_into_wall",
    "plan_spot_poses",
    "predict_normal_uncertainty",
    "readings_at_stops",
    "solve_orientation_lm",
    "solve_orientation_minimal",
]

# The two orientation solutions must put the camera axis in the same place to this angle (rad).
AXIS_AGREEMENT_RAD = 1e-9


@dataclass(frozen=True)
class AlignmentResult:
    """Everything the alignment step found, for the cycle record.

    Attributes:
        points_B: the laser points (eq. 1) in the base frame.
        wall: the robust wall plane, normal into the wall, with rejected spots and uncertainty.
        orientation_lm: eq. 13 solved by Levenberg-Marquardt from the current angles.
        orientation_minimal: the closed-form minimal rotation.
        axis_agreement_rad: angle between the camera axes the two solutions give.
        used: which of the two the aligned pose uses.
        rotation_rad: how far the flange turns from its pose at the last spot.
        distance: the distance correction of eq. 14.
        T_B_H_aligned: the flange pose to shoot from (C_Pos_1 of section 4.3).
    """

    points_B: NDArray[np.float64]
    wall: WallPlane
    orientation_lm: FlangeOrientation
    orientation_minimal: FlangeOrientation
    axis_agreement_rad: float
    used: Literal["lm", "minimal"]
    rotation_rad: float
    distance: DistanceCorrection
    T_B_H_aligned: Pose


def readings_at_stops(
    T_B_H_spots: ArrayLike, distances_mm: ArrayLike, stops: Sequence[int]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.intp]] | None:
    """Among spots read standing, those at a sweep's stops (``stops``: their indices), each its own stop, as
    :func:`compute_alignment`'s ``at_rest``; None without stops (the plane's offset then comes from all spots)."""
    if not len(stops):
        return None
    k = np.asarray(stops, dtype=int)
    return np.asarray(T_B_H_spots, dtype=float)[k], np.asarray(distances_mm, dtype=float)[k], np.arange(k.size)


def compute_alignment(
    T_B_H_spots: ArrayLike,
    distances_mm: ArrayLike,
    r: ArrayLike,
    l: ArrayLike,  # noqa: E741
    T_H_C: ArrayLike,
    working_distance_mm: float,
    *,
    T_B_H_current: ArrayLike | None = None,
    range_mm: tuple[float, float] | None = None,
    inlier_threshold_mm: float = 0.5,
    max_rms_mm: float | None = None,
    min_collinearity: float = 1e-3,
    sigma_prior_mm: float | None = None,
    orientation: Literal["lm", "minimal"] = "minimal",
    at_rest: tuple[ArrayLike, ArrayLike] | tuple[ArrayLike, ArrayLike, ArrayLike] | None = None,
    min_rest_points: int = 10,
) -> AlignmentResult:
    """Laser spots in, aligned shooting pose out (paper section 3).

    The flange turns about the camera's optical centre so the camera's z axis lies along the
    wall normal, then moves along that axis to the working distance (eq. 14). The in-plane
    position of the optical centre is kept.

    Args:
        T_B_H_spots: (N, 4, 4) flange poses at the readings.
        distances_mm: (N,) laser distances.
        r, l: laser origin and unit direction in the flange frame.
        T_H_C: camera pose in the flange frame (hand-eye).
        working_distance_mm: the camera-to-wall distance to reach (400 mm in the paper).
        T_B_H_current: the flange pose to correct; default the pose at the last spot (as the paper).
        at_rest: flange poses (M, 4, 4) and distances (M,) of readings a sweep took with the flange
            standing (its stops), and optionally (M,) the stop each was read at (each stop then weighs
            the same): the plane's offset comes from them, its normal from all readings
            (:func:`offset_at_rest`, at least ``min_rest_points`` of them). None: both from all readings (standing spots).
    """
    poses = np.asarray(T_B_H_spots, dtype=float)
    points = laser_points(poses, r, l, distances_mm, range_mm)
    wall = fit_wall_plane(
        points,
        laser_origins(poses, r),
        inlier_threshold_mm=inlier_threshold_mm,
        max_rms_mm=max_rms_mm,
        min_collinearity=min_collinearity,
        sigma_prior_mm=sigma_prior_mm,
    )
    if at_rest is not None:
        rest_points = laser_points(np.asarray(at_rest[0], dtype=float).reshape(-1, 4, 4), r, l, at_rest[1], range_mm)
        stops = at_rest[2] if len(at_rest) == 3 else None
        wall = offset_at_rest(wall, rest_points, inlier_threshold_mm=inlier_threshold_mm, min_points=min_rest_points, stops=stops)
    THC = check_pose(T_H_C, "T_H_C (hand-eye)")
    current = check_pose(poses[-1] if T_B_H_current is None else T_B_H_current, "current flange pose")
    z_C_in_H = THC[:3, 2]
    lm = solve_orientation_lm(current[:3, :3], z_C_in_H, wall.normal)
    minimal = solve_orientation_minimal(current[:3, :3], z_C_in_H, wall.normal)
    agreement = angle_between_vectors(lm.R_B_H @ z_C_in_H, minimal.R_B_H @ z_C_in_H)
    if agreement > AXIS_AGREEMENT_RAD:
        raise AlignmentError(
            f"the LM and closed-form orientations disagree on the camera axis by {agreement:.3g} rad"
        )
    chosen = lm if orientation == "lm" else minimal
    # Turn about the optical centre: it keeps its place, the flange swings around it.
    p_C = (current @ THC)[:3, 3]
    turned = make_pose(chosen.R_B_H, p_C - chosen.R_B_H @ THC[:3, 3])
    distance = correct_distance(turned, THC, wall.plane, working_distance_mm)
    return AlignmentResult(
        points_B=points,
        wall=wall,
        orientation_lm=lm,
        orientation_minimal=minimal,
        axis_agreement_rad=agreement,
        used=orientation,
        rotation_rad=rotation_angle_between(current[:3, :3], chosen.R_B_H),
        distance=distance,
        T_B_H_aligned=distance.T_B_H,
    )
