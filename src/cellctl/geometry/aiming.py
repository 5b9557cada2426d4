"""Where the flange must stand to aim the camera or the laser at the wall: pure pose algebra, no checks of the devices.

Kept apart from the planners (``cellctl.calibration.teach``, ``cellctl.align``) so that the configuration's
reach check at load (``cellctl.config.reach``) plans the same poses without loading their packages.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from cellctl.geometry.pose import Pose, check_pose, make_pose


def nominal_shooting_pose(
    T_B_T0: ArrayLike, T_H_C: ArrayLike, working_distance_mm: float, aim_mm: tuple[float, float] = (0.0, 0.0)
) -> Pose:
    """The flange pose that puts the camera square to the wall at the working distance, its axes
    along T0's and its optical axis through T0's point ``aim_mm`` (the corner by default)."""
    T_T0_C = make_pose(np.eye(3), [float(aim_mm[0]), float(aim_mm[1]), -float(working_distance_mm)])
    return check_pose(T_B_T0, "T_B_T0") @ T_T0_C @ np.linalg.inv(check_pose(T_H_C, "T_H_C"))


def flange_pose_at_spot(spot_X: ArrayLike, R_X_H: ArrayLike, r: ArrayLike, l: ArrayLike, standoff_mm: float) -> Pose:  # noqa: E741
    """The flange pose, with orientation ``R_X_H``, that puts the laser spot (origin ``r``, unit direction ``l`` in
    the flange frame; mm) on ``spot_X`` at ``standoff_mm``: eq. 1 backwards, p_H = spot - R (r + standoff * l)."""
    R = np.asarray(R_X_H, dtype=float)
    return make_pose(R, np.asarray(spot_X, dtype=float) - R @ (np.asarray(r, dtype=float) + standoff_mm * np.asarray(l, dtype=float)))
