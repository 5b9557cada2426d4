"""The calibration planners keep their promises, checked by projecting through OpenCV and intersecting the beam with the
wall independently of the planner: the board inside the image margin in every view, the laser's nominal distance in
the sensor's range at every pose."""

from __future__ import annotations

import cv2
import numpy as np

from cellctl.calibration.board import BoardSpec
from cellctl.calibration.poses import plan_board_views, plan_laser_poses
from cellctl.geometry.pose import Pose, invert_pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix

K = np.array([[5249.574, 0.0, 1014.700], [0.0, 5248.587, 1011.988], [0.0, 0.0, 1.0]])
DIST = np.array([-0.158, -0.0249, -0.0003, 0.0004, 0.0412])
SIZE = (2048, 2048)
T_H_C = make_pose(axis_angle_to_matrix([0.0, 0.0, np.pi / 2]), [-54.874, -75.193, 102.960])
T_B_P = make_pose(axis_angle_to_matrix([0.0, np.pi / 2, 0.0]), [1800.0, 300.0, 1100.0])  # the board on a wall facing -x


def _anywhere(_: Pose) -> None:
    """A robot that reaches every pose: the plans are shaped by the image and the range only."""


def test_every_planned_view_keeps_the_whole_board_the_margin_inside_the_image() -> None:
    outline = BoardSpec((11, 8), 10.0).outline(15.0)
    margin = 250.0
    plan = plan_board_views(
        T_B_P, outline, T_H_C, K, DIST, SIZE, 24, _anywhere, margin_px=margin, tilt_deg=(12.0, 40.0), distance_mm=(550.0, 650.0)
    )
    assert len(plan.flange_poses) >= 12
    for flange in plan.flange_poses:
        T_C_P = invert_pose(flange @ T_H_C) @ T_B_P
        uv, _ = cv2.projectPoints(outline.reshape(-1, 1, 3), cv2.Rodrigues(T_C_P[:3, :3])[0], T_C_P[:3, 3], K, DIST)
        uv = uv.reshape(-1, 2)
        assert np.all(uv >= margin - 1e-6), uv.min(axis=0)
        assert np.all(uv <= np.array(SIZE) - 1 - margin + 1e-6), uv.max(axis=0)


def test_every_planned_laser_pose_reads_the_wall_inside_the_range() -> None:
    W = make_pose(axis_angle_to_matrix([0.0, np.pi / 2, 0.0]), [2200.0, 0.0, 1200.0])  # z (into the wall) along +x of B
    r = np.array([43.6839, -40.4931, 90.1015])
    beam_H = np.array([0.9977, 0.0626, 0.0265]) / np.linalg.norm([0.9977, 0.0626, 0.0265])  # l of eq. 19
    v = np.cross(beam_H, W[:3, 2])
    R0 = axis_angle_to_matrix(v / np.linalg.norm(v) * np.arccos(beam_H @ W[:3, 2]))
    lo, hi = 300.0, 400.0
    plan = plan_laser_poses(W, (0.0, 0.0), R0, r, beam_H, 120, _anywhere, range_mm=(lo, hi))
    assert len(plan.flange_poses) >= 60
    n, D = W[:3, 2], float(W[:3, 2] @ W[:3, 3])
    for flange in plan.flange_poses:
        origin, beam = flange[:3, :3] @ r + flange[:3, 3], flange[:3, :3] @ beam_H
        dist = (D - n @ origin) / (n @ beam)
        assert lo - 1e-6 <= dist <= hi + 1e-6, dist
