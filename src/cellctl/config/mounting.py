"""Camera model, hand-eye transform and laser mounting as configured (the sim's truth, or nominal)."""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from cellctl.config.types import (
    Finite,
    Matrix3Rows,
    StrictModel,
    UnitVec3,
    Vec3,
    as_array,
)
from cellctl.geometry.pose import Pose, make_pose
from cellctl.geometry.rotation import nearest_rotation, rot_x, rot_y


class CameraIntrinsics(StrictModel):
    """Pinhole camera with Brown-Conrady distortion (paper eq. 17), OpenCV conventions."""

    width_px: int = Field(2048, gt=0, le=20000)
    height_px: int = Field(2048, gt=0, le=20000)
    fx: Finite = Field(5249.574, gt=0)
    fy: Finite = Field(5248.587, gt=0)
    cx: Finite = 1014.700
    cy: Finite = 1011.988
    k1: Finite = -0.158
    k2: Finite = -0.0249
    k3: Finite = 0.0412
    p1: Finite = -0.0003
    p2: Finite = 0.0004

    @model_validator(mode="after")
    def _principal_point_inside(self) -> "CameraIntrinsics":
        if not (0 <= self.cx < self.width_px and 0 <= self.cy < self.height_px):
            raise ValueError(
                f"principal point ({self.cx}, {self.cy}) lies outside the {self.width_px} x "
                f"{self.height_px} image; check cx, cy against width_px, height_px"
            )
        return self

    def camera_matrix(self) -> np.ndarray:
        """The 3x3 matrix A of eq. 17."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def dist_coeffs(self) -> np.ndarray:
        """Distortion in OpenCV's order (k1, k2, p1, p2, k3)."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    def field_of_view_mm(self, distance_mm: float) -> tuple[float, float]:
        """Width and height (mm) the image covers on a plane facing the camera at ``distance_mm``."""
        return (self.width_px / self.fx * distance_mm, self.height_px / self.fy * distance_mm)


class HandEye(StrictModel):
    """The camera frame C in the flange frame H: T_H_C (paper eq. 18).

    ``rotation_rows`` is the matrix as printed (it may be rounded: it is re-orthonormalised).
    ``optical_axis_fix`` turns the printed frame into OpenCV's (z along the optical axis, into the
    scene): the paper's printed camera z points away from the laser's direction, i.e. away from the
    wall, so the twin mounts the camera rotated by 180 deg about its own x axis ("flip_about_x"),
    which keeps the image's u axis and turns the optical axis to face the wall with the laser.
    """

    translation_mm: Vec3 = (-54.874, -75.193, 102.960)
    rotation_rows: Matrix3Rows = (
        (0.007, -0.036, -0.999),
        (1.0, 0.0074, 0.006),
        (0.007, -0.998, 0.036),
    )
    optical_axis_fix: Literal["none", "flip_about_x", "flip_about_y"] = "flip_about_x"

    @model_validator(mode="after")
    def _near_rotation(self) -> "HandEye":
        R = as_array(self.rotation_rows)
        if np.max(np.abs(R.T @ R - np.eye(3))) > 0.05 or np.linalg.det(R) < 0.9:
            raise ValueError(
                "rotation_rows is not a (rounded) rotation matrix: rows must be orthonormal within "
                "0.05 and the determinant +1; copy all nine values from the calibration report"
            )
        return self

    def T_H_C(self) -> Pose:
        """The camera pose in the flange frame, re-orthonormalised and with the axis fix applied."""
        R = nearest_rotation(as_array(self.rotation_rows))
        if self.optical_axis_fix == "flip_about_x":
            R = R @ rot_x(np.pi)
        elif self.optical_axis_fix == "flip_about_y":
            R = R @ rot_y(np.pi)
        return make_pose(R, self.translation_mm)


class LaserMount(StrictModel):
    """The laser ray in the flange frame (paper eq. 19) and the sensor's measuring range."""

    origin_mm: Vec3 = (43.6839, -40.4931, 90.1015)
    direction: UnitVec3 = (0.9977, 0.0626, 0.0265)
    range_min_mm: Finite = Field(250.0, gt=0)
    range_max_mm: Finite = Field(450.0, gt=0)

    @model_validator(mode="after")
    def _range_order(self) -> "LaserMount":
        if self.range_min_mm >= self.range_max_mm:
            raise ValueError(
                f"range_min_mm ({self.range_min_mm}) must be below range_max_mm ({self.range_max_mm})"
            )
        return self

    @property
    def r(self) -> np.ndarray:
        """Laser origin r in H (mm)."""
        return as_array(self.origin_mm)

    @property
    def l(self) -> np.ndarray:  # noqa: E743 - the paper's name for the laser direction
        """Unit laser direction l in H."""
        return as_array(self.direction)

    @property
    def full_scale_mm(self) -> float:
        """The measuring span (mm) that linearity is quoted against."""
        return self.range_max_mm - self.range_min_mm
