"""Pixel to workpiece millimetres at the taught shooting pose (paper 4.1): scale s and the nine-point map.

Both are thin layers over cellctl.vision (eq. 15 in ``checkerboard_scale``, the affine fit in
``fit_affine_map``); this module says where their data comes from.

The nine-point map is measured with the robot, the usual way for a camera on the robot: from the
taught shooting pose C_Pos_0 the robot shifts the camera to a 3 x 3 grid of offsets o_k in the
wall plane, along the taught workpiece frame's x and y axes, and the corner detector measures
the window corner in each image. Shifting the camera by o_k makes the fixed corner appear where a
point at -o_k would appear from C_Pos_0, so the pairs (corner pixel_k, -o_k) give the map from
undistorted pixels to millimetres in T0's axes, exactly the frame the cycle's offset T' is
applied in. The offsets are taken from the poses the robot reports after each move; over a few
centimetres the robot's absolute-accuracy error barely changes, its repeatability (about
0.03 mm per axis) goes into the map's residuals.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.calibration.errors import CalibrationRefused
from cellctl.geometry.pose import Pose, check_pose, make_pose
from cellctl.vision.ninepoint import AffineMap, fit_affine_map

F64 = NDArray[np.float64]

MAP_SCALE_TOLERANCE = 0.03
"""How far (relative) the nine-point map's scale along any image direction may differ from the pixel
scale s of eq. 15; the twin's maps agree within 0.2 % (seeds 1-5), a wrong board size or robot offset is far off."""


def nine_point_offsets(step_mm: float) -> F64:
    """The 3 x 3 grid of camera offsets (9, 2) in mm, row by row, centre first."""
    if not np.isfinite(step_mm) or step_mm <= 0:
        raise ValueError(f"step_mm must be a positive number, got {step_mm!r}")
    grid = [(0.0, 0.0)] + [(i * step_mm, j * step_mm) for j in (-1, 0, 1) for i in (-1, 0, 1) if (i, j) != (0, 0)]
    return np.asarray(grid, dtype=float)


def nine_point_targets(C_Pos_0: ArrayLike, T0: ArrayLike, offsets_mm: ArrayLike) -> list[Pose]:
    """Flange targets: C_Pos_0 shifted by each offset along T0's x and y axes (orientation kept)."""
    C = check_pose(C_Pos_0, "C_Pos_0")
    R = check_pose(T0, "T0")[:3, :3]
    out = []
    for o in np.asarray(offsets_mm, dtype=float):
        out.append(make_pose(C[:3, :3], C[:3, 3] + R @ np.array([o[0], o[1], 0.0])))
    return out


def offsets_from_poses(T_B_H: Sequence[ArrayLike], reference: ArrayLike, T0: ArrayLike) -> F64:
    """The in-plane offsets (N, 2) of reported flange poses from ``reference``, along T0's x and y."""
    R = check_pose(T0, "T0")[:3, :3]
    ref = check_pose(reference, "reference pose")[:3, 3]
    return np.array([(R.T @ (check_pose(h, "flange pose")[:3, 3] - ref))[:2] for h in T_B_H])


def nine_point_map(corners_ideal_px: ArrayLike, offsets_mm: ArrayLike) -> AffineMap:
    """The map from undistorted pixels to T0 millimetres: the corner seen at pixel_k is at -o_k."""
    P = np.asarray(corners_ideal_px, dtype=float)
    O = np.asarray(offsets_mm, dtype=float)
    return fit_affine_map(P, -O)


def accept_nine_point_map(amap: AffineMap, s_mm_per_px: float, *, tolerance: float = MAP_SCALE_TOLERANCE) -> float:
    """Check the map against the camera model; returns its mean scale's relative difference from s.

    The camera looks square onto the wall, so the map is nearly a similarity: it keeps the image's
    handedness (u right and v down onto T0's x right and y down: det of its 2 x 2 part > 0) and
    scales every image direction (its singular values, mm/px) by the pixel scale s of eq. 15 within
    ``tolerance``. Raises CalibrationRefused (reason ``mirrored_map`` or ``map_scale``) naming the figures.
    """
    if not np.isfinite(s_mm_per_px) or s_mm_per_px <= 0:
        raise ValueError(f"s_mm_per_px must be a positive number, got {s_mm_per_px!r}")
    L = amap.linear
    det = float(np.linalg.det(L))
    if not det > 0:
        raise CalibrationRefused("pixel_map", "mirrored_map", (
            f"the nine-point map is mirrored (det of its 2 x 2 part {det:.3g} mm^2/px^2, must be > 0: the image's u right "
            "and v down map onto T0's x right and y down): check that the camera's ReverseX / ReverseY are as at the "
            "camera calibration (off), and the signs of the robot's offsets (the flange poses along T0's x and y)"))
    sv = np.linalg.svd(L, compute_uv=False)  # mm/px along the image's most and least stretched directions
    worst = float(np.max(np.abs(sv / s_mm_per_px - 1.0)))
    if worst > tolerance:
        raise CalibrationRefused("pixel_map", "map_scale", (
            f"the nine-point map scales the image by {sv[0]:.6f} to {sv[1]:.6f} mm/px, the pixel scale s (eq. 15, the "
            f"scale board) is {s_mm_per_px:.6f} mm/px: {worst:.1%} apart, over the {tolerance:.0%} allowed "
            "(cellctl.calibration.pixel_map.MAP_SCALE_TOLERANCE): check the square size given for the scale board, "
            "the robot's offsets (units, tool and work object), the camera's binning or decimation since its "
            "calibration, and that the camera shot from the taught pose"))
    return abs(amap.mm_per_px / s_mm_per_px - 1.0)
