"""The twin camera's geometry: projection against OpenCV, and the cached inverse of the distortion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.config.mounting import CameraIntrinsics, HandEye
from cellctl.geometry.pose import apply_pose, invert_pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix
from cellctl.sim.camera_model import CameraModel, DistortionNotInvertible, ray_map

INTR = CameraIntrinsics()


@pytest.fixture(scope="module")
def camera() -> CameraModel:
    return CameraModel(INTR)


def _cv2_project(points_B: np.ndarray, T_B_C: np.ndarray) -> np.ndarray:
    T_C_B = invert_pose(T_B_C)
    rvec, _ = cv2.Rodrigues(T_C_B[:3, :3])
    uv, _ = cv2.projectPoints(points_B.reshape(-1, 1, 3), rvec, T_C_B[:3, 3], INTR.camera_matrix(), INTR.dist_coeffs())
    return uv.reshape(-1, 2)


def test_project_agrees_with_cv2_project_points(camera: CameraModel) -> None:
    rng = np.random.default_rng(11)
    for _ in range(5):
        T_B_C = make_pose(axis_angle_to_matrix(rng.normal(0, 0.5, 3)), rng.uniform(-2000, 2000, 3))
        # Points over (and a little beyond) the field of view at 300..600 mm.
        xy = rng.uniform(-0.25, 0.25, (400, 2))
        z = rng.uniform(300, 600, 400)
        P_C = np.column_stack([xy * z[:, None], z])
        P_B = apply_pose(T_B_C, P_C)
        ours = camera.project(P_B, T_B_C)
        theirs = _cv2_project(P_B, T_B_C)
        assert np.max(np.abs(ours - theirs)) < 1e-6


def test_points_behind_the_camera_are_refused(camera: CameraModel) -> None:
    with pytest.raises(ValueError, match="behind the camera"):
        camera.project_camera(np.array([[0.0, 0.0, 400.0], [10.0, 0.0, -5.0]]))


def test_ray_map_is_accurate_everywhere_in_the_image() -> None:
    rays = ray_map(INTR, INTR.height_px, INTR.width_px)
    # Its own check: every ray distorted again lands on its pixel.
    assert rays.max_residual_px < 1e-6
    # Independently, through OpenCV's forward model, on every 7th pixel of the whole image
    # (including the four corners, where the distortion is largest).
    rows = np.unique(np.r_[np.arange(0, INTR.height_px, 7), INTR.height_px - 1])
    cols = np.unique(np.r_[np.arange(0, INTR.width_px, 7), INTR.width_px - 1])
    x = rays.x[np.ix_(rows, cols)].ravel()
    y = rays.y[np.ix_(rows, cols)].ravel()
    pts = np.column_stack([x, y, np.ones_like(x)]).reshape(-1, 1, 3)
    uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), INTR.camera_matrix(), INTR.dist_coeffs())
    vv, uu = np.meshgrid(rows, cols, indexing="ij")
    err = np.hypot(uv[:, 0, 0] - uu.ravel(), uv[:, 0, 1] - vv.ravel())
    assert err.max() < 1e-4  # "well under 0.01 px"; in fact ~1e-9
    # The distortion is not negligible there: the corner pixels' rays are several px from the
    # undistorted guess, so the inversion is doing real work.
    guess = (INTR.width_px - 1 - INTR.cx) / INTR.fx
    assert abs(rays.x[-1, -1] - guess) * INTR.fx > 5.0


def test_ray_map_agrees_with_cv2_undistort(camera: CameraModel) -> None:
    rng = np.random.default_rng(5)
    uv = rng.uniform(0, 2047, (500, 2))
    ours = camera.undistort_pixels(uv)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    theirs = cv2.undistortPointsIter(uv.reshape(-1, 1, 2), INTR.camera_matrix(), INTR.dist_coeffs(), None, None, crit)
    assert np.max(np.abs(ours - theirs.reshape(-1, 2))) * INTR.fx < 1e-3


def test_a_folding_distortion_is_refused_naming_the_coefficients() -> None:
    # With k1 = -10 the radial map r (1 + k1 r^2) turns back at r = 0.18, inside the image.
    bad = CameraIntrinsics(k1=-10.0, k2=0.0, k3=0.0)
    with pytest.raises(DistortionNotInvertible, match="k1=-10.0"):
        CameraModel(bad).undistort_pixels([[1000.0, 1000.0], [0.0, 0.0], [2047.0, 2047.0]])


def test_hand_eye_mounting_faces_the_wall_with_the_laser() -> None:
    # The camera's optical axis (z of C) and the laser point the same way in the flange frame.
    T_H_C = HandEye().T_H_C()
    laser_dir = np.array([0.9977, 0.0626, 0.0265])
    assert T_H_C[:3, 2] @ laser_dir > 0.99
