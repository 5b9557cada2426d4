"""Teaching, paper 4.3 step 1: the workpiece frame T0, the shooting pose C_Pos_0, the template, g_Pos_0.

With the car body standing where it stands at teaching:

1. Laser alignment (paper section 3, cellctl.align) from a shooting pose planned on the layout's
   nominal corner: the laser measures the wall around the opening and the flange turns and moves
   so the camera looks square onto the wall at the working distance. That pose is C_Pos_0.
2. One image at C_Pos_0; the corner detector gives the template (u_d, v_d, theta_d) in the ideal
   (undistorted) image.
3. T0 is the workpiece frame that this image and the measured wall define, all in the robot's
   base frame as the controller sees it: origin where the corner's ray (through the calibrated
   camera at C_Pos_0) meets the measured wall plane, z the wall normal into the wall, x along the
   top edge's image direction (theta_d) carried onto the wall, y = z x x (down). So T0, C_Pos_0
   and the template describe one and the same corner.
4. g_Pos_0 is the flange pose with the glass correctly installed: the operator guides the glass
   in by hand several times (``calibration.procedure.teach.hand_guided_installs``), the
   controller's pose is recorded each time, and g_Pos_0 is their mean; how far the installs
   put the window corner from the mean is reported, and too wide a spread is refused
   (cellctl.calibration.compute).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.geometry.pose import Pose, check_pose, make_pose

F64 = NDArray[np.float64]


def _ray_on_plane(T_B_C: F64, K: F64, uv_ideal: F64, normal: F64, offset: float) -> F64:
    x = (uv_ideal[0] - K[0, 2]) / K[0, 0]
    y = (uv_ideal[1] - K[1, 2]) / K[1, 1]
    d = T_B_C[:3, :3] @ np.array([x, y, 1.0])
    o = T_B_C[:3, 3]
    denom = float(normal @ d)
    if abs(denom) < 1e-9:
        raise ValueError("the camera ray runs parallel to the wall plane")
    lam = (offset - float(normal @ o)) / denom
    if lam <= 0:
        raise ValueError("the wall plane lies behind the camera")
    return o + lam * d


def workpiece_frame_from_corner(
    C_Pos_0: ArrayLike,
    T_H_C: ArrayLike,
    K: ArrayLike,
    corner_ideal_px: ArrayLike,
    theta_rad: float,
    wall_normal: ArrayLike,
    wall_offset_mm: float,
) -> Pose:
    """T0 at the corner seen at ``corner_ideal_px`` on the wall n . p = D (n into the wall), in B.

    Args:
        C_Pos_0: the flange pose the image was taken from.
        T_H_C: the calibrated hand-eye transform.
        K: the camera matrix A (the ideal image uses it without distortion).
        corner_ideal_px: (u_d, v_d), the corner in the ideal image.
        theta_rad: the corner's angle in the image (the top edge's direction is (cos, sin)).
        wall_normal, wall_offset_mm: the wall plane from the laser, normal pointing into the wall.
    """
    T_B_C = check_pose(C_Pos_0, "C_Pos_0") @ check_pose(T_H_C, "T_H_C")
    Km = np.asarray(K, dtype=float)
    n = np.asarray(wall_normal, dtype=float)
    n = n / np.linalg.norm(n)
    uv = np.asarray(corner_ideal_px, dtype=float)
    p0 = _ray_on_plane(T_B_C, Km, uv, n, wall_offset_mm)
    step = 200.0  # px along the top edge's direction
    p1 = _ray_on_plane(T_B_C, Km, uv + step * np.array([np.cos(theta_rad), np.sin(theta_rad)]), n, wall_offset_mm)
    x = p1 - p0
    x -= (x @ n) * n
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    return make_pose(np.column_stack([x, y, n]), p0)
