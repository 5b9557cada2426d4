"""The nine-point map's scale check, and T0 from the corner's ray and the wall, against a pinhole camera of known pose.

The camera looks at a wall z = 1400 mm in B from a known flange pose; OpenCV's projectPoints (no distortion: the
ideal image) gives the pixels of known wall points, so the map and T0 have a known answer.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.pixel_map import accept_nine_point_map, nine_point_map, nine_point_offsets
from cellctl.calibration.teach import workpiece_frame_from_corner
from cellctl.geometry.pose import invert_pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix

WALL_N, WALL_D = np.array([0.0, 0.0, 1.0]), 1400.0
T_H_C = make_pose(axis_angle_to_matrix([0.0, 0.0, np.pi / 2]), [-54.874, -75.193, 102.960])


def _pixels(K: np.ndarray, T_B_C: np.ndarray, points_B: np.ndarray) -> np.ndarray:
    T_C_B = invert_pose(T_B_C)
    rvec, _ = cv2.Rodrigues(T_C_B[:3, :3])
    uv, _ = cv2.projectPoints(np.asarray(points_B, float).reshape(-1, 1, 3), rvec, T_C_B[:3, 3], K, np.zeros(5))
    return uv.reshape(-1, 2)


def _camera_facing_the_wall(tilt_deg: float = 8.0) -> np.ndarray:
    """T_B_C of a camera 400 mm before the wall, its z axis tilted ``tilt_deg`` from the wall's normal."""
    R = axis_angle_to_matrix(np.deg2rad([tilt_deg, -0.6 * tilt_deg, 20.0]))
    return make_pose(R, np.array([300.0, -200.0, WALL_D]) - 400.0 * R[:, 2])


def test_a_map_true_along_one_image_axis_and_ten_percent_off_along_the_other_is_refused() -> None:
    # Corner pixels for the nine offsets at a known 0.08 mm/px along u but 0.088 along v (a robot's y offsets 10 % off):
    # the mean scale is within 5 % of s, the v direction is not; every direction must agree with s.
    s = 0.08
    offsets = nine_point_offsets(5.0)
    pixels = np.column_stack([-offsets[:, 0] / s, -offsets[:, 1] / (1.1 * s)]) + [1024.0, 1024.0]
    with pytest.raises(CalibrationRefused) as err:
        accept_nine_point_map(nine_point_map(pixels, offsets), s)
    assert err.value.reason == "map_scale"
    true = np.column_stack([-offsets[:, 0] / s, -offsets[:, 1] / s]) + [1024.0, 1024.0]
    assert accept_nine_point_map(nine_point_map(true, offsets), s) < 1e-9


def test_t0_sits_on_the_wall_where_the_corner_is_for_a_camera_with_oblong_pixels() -> None:
    # fy 20 % below fx (binning 1 x 1.25, or an anamorphic lens): the corner's ray must use each axis's own focal length.
    K = np.array([[5000.0, 0.0, 1020.0], [0.0, 4000.0, 990.0], [0.0, 0.0, 1.0]])
    T_B_C = _camera_facing_the_wall()
    C_Pos_0 = T_B_C @ invert_pose(T_H_C)
    corner = np.array([320.0, -170.0, WALL_D])
    edge = np.array([np.cos(0.3), np.sin(0.3), 0.0])  # the top edge's direction on the wall
    uv = _pixels(K, T_B_C, np.array([corner, corner + 50.0 * edge]))
    theta = float(np.arctan2(*(uv[1] - uv[0])[::-1]))
    T0 = workpiece_frame_from_corner(C_Pos_0, T_H_C, K, uv[0], theta, WALL_N, WALL_D)
    assert np.linalg.norm(T0[:3, 3] - corner) < 1e-6
    assert np.degrees(np.arccos(np.clip(T0[:3, 0] @ edge, -1.0, 1.0))) < 1e-6
    assert np.allclose(T0[:3, 2], WALL_N)
    assert np.allclose(T0[:3, 1], np.cross(WALL_N, edge), atol=1e-9)  # y = z x x: down the wall beside the top edge


def test_a_wall_behind_the_camera_is_refused() -> None:
    K = np.array([[5000.0, 0.0, 1020.0], [0.0, 5000.0, 990.0], [0.0, 0.0, 1.0]])
    T_B_C = _camera_facing_the_wall()
    C_Pos_0 = T_B_C @ invert_pose(T_H_C)
    behind = 2.0 * float(T_B_C[2, 3]) - WALL_D  # the wall mirrored through the camera: the ray meets it behind the lens
    with pytest.raises(ValueError, match="behind the camera"):
        workpiece_frame_from_corner(C_Pos_0, T_H_C, K, [1020.0, 990.0], 0.0, WALL_N, behind)
