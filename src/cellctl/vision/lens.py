"""The lens: Brown-Conrady distortion (paper eq. 17, OpenCV's model and order k1, k2, p1, p2, k3).

On normalised coordinates (x, y) = (X/Z, Y/Z) in the camera frame C, r^2 = x^2 + y^2:

    x' = x R + 2 p1 x y + p2 (r^2 + 2 x^2),   y' = y R + p1 (r^2 + 2 y^2) + 2 p2 x y,
    R = 1 + k1 r^2 + k2 r^4 + k3 r^6,          u = fx x' + cx,   v = fy y' + cy  (px).

The pure functions below are the one implementation (the twin's camera uses them too); its inverse
is Newton's method. :class:`Lens` is the calibrated lens the corner detector uses: it undistorts
measured points, not the image (exact, and cheaper than resampling); ideal pixels keep the camera
matrix A.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.config.mounting import CameraIntrinsics

F64 = NDArray[np.float64]
Coefficients = tuple[float, float, float, float, float]  # (k1, k2, p1, p2, k3), OpenCV's order

_NEWTON_ITERATIONS = 20
_NEWTON_TOLERANCE = 1e-13  # normalised units: about 5e-10 px at f = 5250 px
_FOLD_DET = 1e-9  # a distortion Jacobian this flat means the model folds over


class LensFoldsOver(ValueError):
    """The distortion's Jacobian is not positive at some point: it has no unique inverse there."""


def distort_normalised(x: F64, y: F64, dist: Coefficients) -> tuple[F64, F64]:
    """Distorted normalised coordinates (x', y') of ideal ones (x, y) (eq. 17)."""
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy = x * y
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    return xd, yd


def distortion_jacobian(x: F64, y: F64, dist: Coefficients) -> tuple[F64, F64, F64]:
    """d(x', y')/d(x, y) = [[a, b], [b, d]] (it is symmetric), returned as (a, b, d)."""
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    b = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    d = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return a, b, d


def undistort_normalised(
    xd: ArrayLike,
    yd: ArrayLike,
    dist: Coefficients,
    *,
    stop: float,
    max_iter: int,
    scale: float = 1.0,
    fold_det: float | None = None,
) -> tuple[F64, F64, bool]:
    """Ideal normalised coordinates of distorted ones by Newton's method, started at (xd, yd).

    Stops when ``max(|ex| + |ey|) * scale < stop`` (e the distortion residual); returns (x, y,
    converged). With ``fold_det`` a Jacobian determinant at or below it raises LensFoldsOver;
    without, a flat Jacobian is clamped to 1e-12 and the caller checks the result.
    """
    xd = np.asarray(xd, dtype=np.float64)
    yd = np.asarray(yd, dtype=np.float64)
    x = np.array(xd, dtype=np.float64, copy=True)
    y = np.array(yd, dtype=np.float64, copy=True)
    for _ in range(max_iter):
        fx, fy = distort_normalised(x, y, dist)
        ex, ey = fx - xd, fy - yd
        if ex.size == 0 or float(np.max(np.abs(ex) + np.abs(ey))) * scale < stop:
            return x, y, True
        a, b, d = distortion_jacobian(x, y, dist)
        det = a * d - b * b
        if fold_det is not None and np.any(det <= fold_det):
            raise LensFoldsOver(
                "the lens distortion folds over at some of these points; check the calibrated "
                "coefficients (k1, k2, p1, p2, k3) and that the points lie inside the image"
            )
        det = np.where(np.abs(det) > 1e-12, det, 1e-12)
        x = x - (d * ex - b * ey) / det
        y = y - (a * ey - b * ex) / det
    return x, y, False


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
    """Camera matrix A (px) and distortion (k1, k2, p1, p2, k3) in OpenCV's order, with image size."""

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

    def to_square(self, ideal_px: ArrayLike) -> F64:
        """Ideal px to square px (v scaled by fx / fy about cy): a circle on a wall square to the
        camera images as a circle only where both axes have the same focal length, fx."""
        P = np.array(ideal_px, dtype=np.float64).reshape(-1, 2)
        P[:, 1] = self.cy + (P[:, 1] - self.cy) * (self.fx / self.fy)
        return P

    def from_square(self, square_px: ArrayLike) -> F64:
        """The inverse of :meth:`to_square`."""
        P = np.array(square_px, dtype=np.float64).reshape(-1, 2)
        P[:, 1] = self.cy + (P[:, 1] - self.cy) * (self.fy / self.fx)
        return P

    @property
    def dist_coeffs(self) -> F64:
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    @property
    def coefficients(self) -> Coefficients:
        """(k1, k2, p1, p2, k3) as numbers, for the functions above."""
        return (self.k1, self.k2, self.p1, self.p2, self.k3)

    def distort(self, ideal_px: ArrayLike) -> F64:
        """Raw image positions (N, 2) of ideal (undistorted) pixel positions (N, 2)."""
        P = _as_points(ideal_px, "ideal pixel positions")
        xd, yd = distort_normalised((P[:, 0] - self.cx) / self.fx, (P[:, 1] - self.cy) / self.fy, self.coefficients)
        return np.column_stack([self.fx * xd + self.cx, self.fy * yd + self.cy])

    def undistort(self, raw_px: ArrayLike) -> F64:
        """Ideal pixel positions (N, 2) of raw image positions (N, 2), to about 1e-9 px.

        Raises ValueError where the distortion model cannot be inverted (it folds over).
        """
        P = _as_points(raw_px, "raw pixel positions")
        xd = (P[:, 0] - self.cx) / self.fx
        yd = (P[:, 1] - self.cy) / self.fy
        dist = self.coefficients
        x, y, converged = undistort_normalised(
            xd, yd, dist, stop=_NEWTON_TOLERANCE, max_iter=_NEWTON_ITERATIONS, fold_det=_FOLD_DET
        )
        if not converged:
            fx, fy = distort_normalised(x, y, dist)
            if float(np.max(np.hypot((fx - xd) * self.fx, (fy - yd) * self.fy))) > 1e-6:
                raise ValueError("undistorting points did not converge; check the distortion coefficients")
        return np.column_stack([self.fx * x + self.cx, self.fy * y + self.cy])

    def square_of_raw(self, raw_px: ArrayLike) -> F64:
        """Raw image positions (N, 2) in the ideal image with square pixels: :meth:`undistort`, then :meth:`to_square`."""
        return self.to_square(self.undistort(raw_px))

    def check_size(self, image: NDArray[np.generic]) -> None:
        """Raise ValueError unless the image has this lens's size."""
        if image.shape[:2] != (self.height_px, self.width_px):
            raise ValueError(
                f"image is {image.shape[1]} x {image.shape[0]} px but the lens is calibrated for "
                f"{self.width_px} x {self.height_px} px; use the calibration of this camera"
            )

    def check_image(self, image: object) -> NDArray[np.uint8]:
        """The image, if it is a 2-D uint8 grey image of this lens's size; else ValueError."""
        if not isinstance(image, np.ndarray) or image.ndim != 2 or image.dtype != np.uint8:
            raise ValueError(f"image must be a 2-D uint8 numpy array, got {getattr(image, 'dtype', type(image).__name__)}")
        self.check_size(image)
        return image

    def undistort_image(self, image: NDArray[np.generic]) -> NDArray[np.generic]:
        """The whole image resampled onto the ideal pinhole model (same camera matrix A)."""
        self.check_size(image)
        return cv2.undistort(image, self.camera_matrix, self.dist_coeffs, None, self.camera_matrix)
