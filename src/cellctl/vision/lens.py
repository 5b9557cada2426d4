"""The calibrated lens: Brown-Conrady distortion (paper eq. 17) applied and removed.

The corner detector measures edges in the raw image and undistorts the measured points, not the
image: undistorting points is exact (Newton's method to 1e-9 px), whereas resampling the whole
image interpolates grey levels, which blurs the edges and moves them by a phase-dependent amount,
and costs about as much as the rest of the detector on a 2048 x 2048 frame. The checkerboard
scale (eq. 15) works on an undistorted image, see :meth:`Lens.undistort_image`.

Ideal ("undistorted") pixel coordinates use the same camera matrix A as the raw image, so a point
near the principal point keeps its position.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.config.mounting import CameraIntrinsics

F64 = NDArray[np.float64]

_NEWTON_ITERATIONS = 20
_NEWTON_TOLERANCE = 1e-13  # normalised units: about 5e-10 px at f = 5250 px


def _as_points(points: ArrayLike, what: str) -> F64:
    P = np.asarray(points, dtype=float)
    if P.ndim == 1 and P.shape == (2,):
        P = P[None, :]
    if P.ndim != 2 or P.shape[1] != 2:
        raise ValueError(f"{what} must have shape (N, 2), got {np.shape(points)}")
    if not np.all(np.isfinite(P)):
        raise ValueError(f"{what} contain NaN or infinite values")
    return P


@dataclass(frozen=True)
class Lens:
    """Camera matrix A and distortion (k1, k2, p1, p2, k3) in OpenCV's order, with image size."""

    fx: float
    fy: float
    cx: float
    cy: float
    k1: float
    k2: float
    p1: float
    p2: float
    k3: float
    width_px: int
    height_px: int

    @classmethod
    def from_intrinsics(cls, intrinsics: CameraIntrinsics) -> "Lens":
        i = intrinsics
        return cls(i.fx, i.fy, i.cx, i.cy, i.k1, i.k2, i.p1, i.p2, i.k3, i.width_px, i.height_px)

    @property
    def camera_matrix(self) -> F64:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> F64:
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    def _distort_normalised(self, x: F64, y: F64) -> tuple[F64, F64]:
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xy = x * y
        xd = x * radial + 2.0 * self.p1 * xy + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * xy
        return xd, yd

    def distort(self, ideal_px: ArrayLike) -> F64:
        """Raw image positions (N, 2) of ideal (undistorted) pixel positions (N, 2)."""
        P = _as_points(ideal_px, "ideal pixel positions")
        xd, yd = self._distort_normalised((P[:, 0] - self.cx) / self.fx, (P[:, 1] - self.cy) / self.fy)
        return np.column_stack([self.fx * xd + self.cx, self.fy * yd + self.cy])

    def undistort(self, raw_px: ArrayLike) -> F64:
        """Ideal pixel positions (N, 2) of raw image positions (N, 2), by Newton's method.

        Raises ValueError if the distortion model cannot be inverted there (it folds over).
        """
        P = _as_points(raw_px, "raw pixel positions")
        xd = (P[:, 0] - self.cx) / self.fx
        yd = (P[:, 1] - self.cy) / self.fy
        x, y = xd.copy(), yd.copy()
        k1, k2, k3, p1, p2 = self.k1, self.k2, self.k3, self.p1, self.p2
        for _ in range(_NEWTON_ITERATIONS):
            fx_, fy_ = self._distort_normalised(x, y)
            ex, ey = fx_ - xd, fy_ - yd
            if ex.size == 0 or float(np.max(np.abs(ex) + np.abs(ey))) < _NEWTON_TOLERANCE:
                break
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
            a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
            b = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
            d = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
            det = a * d - b * b
            if np.any(det <= 1e-9):
                raise ValueError(
                    "the lens distortion folds over at some of these points; check the calibrated "
                    "coefficients (k1, k2, p1, p2, k3) and that the points lie inside the image"
                )
            x = x - (d * ex - b * ey) / det
            y = y - (a * ey - b * ex) / det
        else:
            fx_, fy_ = self._distort_normalised(x, y)
            if float(np.max(np.hypot((fx_ - xd) * self.fx, (fy_ - yd) * self.fy))) > 1e-6:
                raise ValueError("undistorting points did not converge; check the distortion coefficients")
        return np.column_stack([self.fx * x + self.cx, self.fy * y + self.cy])

    def undistort_image(self, image: NDArray[np.generic]) -> NDArray[np.generic]:
        """The whole image resampled onto the ideal pinhole model (same camera matrix A)."""
        if image.shape[:2] != (self.height_px, self.width_px):
            raise ValueError(
                f"image is {image.shape[1]} x {image.shape[0]} px but the lens is calibrated for "
                f"{self.width_px} x {self.height_px} px"
            )
        return cv2.undistort(image, self.camera_matrix, self.dist_coeffs, None, self.camera_matrix)
