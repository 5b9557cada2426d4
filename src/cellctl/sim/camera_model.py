"""The twin camera's geometry: pinhole projection with the lens distortion of paper eq. 17.

OpenCV's conventions: camera frame C (x right, y down, z along the optical axis); pixel (u, v),
u right, v down, the centre of pixel [row i, column j] at (u, v) = (j, i). The distortion and its
Newton inverse are :mod:`cellctl.vision.lens`'s. The renderer needs the ray through every pixel
centre: :func:`ray_map` computes it once per set of intrinsics and caches it, checking that every
ray re-distorts onto its pixel to 1e-6 px and refusing a model that folds over inside the image.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.config.mounting import CameraIntrinsics
from cellctl.geometry.pose import apply_pose, check_pose, invert_pose
from cellctl.vision.lens import Coefficients, distort_normalised, distortion_jacobian, undistort_normalised

F64 = NDArray[np.float64]

# The ray map must reproduce its pixel to this accuracy (px) when distorted again.
RAY_MAP_TOLERANCE_PX = 1e-6
_NEWTON_MAX_ITER = 30


class DistortionNotInvertible(ValueError):
    """The distortion coefficients fold the image over: some pixel has no unique ray."""


@dataclass(frozen=True)
class RayMap:
    """Undistorted normalised coordinates (x, y) of the ray through pixel centres.

    ``x[i, j], y[i, j]`` belong to pixel (u, v) = (j, i). The map covers ``rows`` x ``cols`` pixels,
    which may extend past the image (the renderer pads to whole blocks plus one row and column).
    ``max_residual_px`` is the largest distance between a pixel and its ray distorted again.
    """

    x: F64
    y: F64
    max_residual_px: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.x.shape  # type: ignore[return-value]


class CameraModel:
    """Projection and back-projection for one set of intrinsics (px, camera frame C)."""

    def __init__(self, intrinsics: CameraIntrinsics) -> None:
        self.intrinsics = intrinsics
        self.width = intrinsics.width_px
        self.height = intrinsics.height_px
        self.fx, self.fy = intrinsics.fx, intrinsics.fy
        self.cx, self.cy = intrinsics.cx, intrinsics.cy
        self.k1, self.k2, self.k3 = intrinsics.k1, intrinsics.k2, intrinsics.k3
        self.p1, self.p2 = intrinsics.p1, intrinsics.p2
        self.dist: Coefficients = (self.k1, self.k2, self.p1, self.p2, self.k3)

    def distort_normalized(self, x: F64, y: F64) -> tuple[F64, F64]:
        """Distorted normalised coordinates (x', y') of undistorted ones (x, y) (eq. 17)."""
        return distort_normalised(x, y, self.dist)

    def normalized_to_pixels(self, x: ArrayLike, y: ArrayLike) -> tuple[F64, F64]:
        """Pixel coordinates (u, v) of undistorted normalised coordinates, with distortion."""
        xd, yd = self.distort_normalized(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        return self.fx * xd + self.cx, self.fy * yd + self.cy

    def project_camera(self, points_C: ArrayLike) -> F64:
        """Pixel coordinates (N, 2) of points (N, 3, mm) in the camera frame C; refuses points with Z <= 0."""
        P = np.atleast_2d(np.asarray(points_C, dtype=float))
        if P.ndim != 2 or P.shape[1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {np.shape(points_C)}")
        if not np.all(np.isfinite(P)):
            raise ValueError("points contain NaN or infinite values")
        behind = np.flatnonzero(P[:, 2] <= 0.0)
        if behind.size:
            raise ValueError(
                f"{behind.size} point(s) lie behind the camera (Z <= 0 in the camera frame), "
                f"first index {int(behind[0])}; they have no image"
            )
        u, v = self.normalized_to_pixels(P[:, 0] / P[:, 2], P[:, 1] / P[:, 2])
        return np.column_stack([u, v])

    def project(self, points_B: ArrayLike, T_B_C: ArrayLike) -> F64:
        """Pixel coordinates (N, 2) of points (N, 3, mm) in the base frame B seen from T_B_C (as ``cv2.projectPoints``)."""
        T = check_pose(T_B_C, "T_B_C")
        return self.project_camera(apply_pose(invert_pose(T), np.atleast_2d(np.asarray(points_B, dtype=float))))

    def undistort_normalized(self, xd: F64, yd: F64) -> tuple[F64, F64, float]:
        """Undistorted normalised coordinates of distorted ones, and the worst re-distortion error (px).

        Raises DistortionNotInvertible when that error exceeds RAY_MAP_TOLERANCE_PX or the
        distortion's Jacobian is not positive somewhere.
        """
        x, y, _ = undistort_normalised(
            xd, yd, self.dist, stop=RAY_MAP_TOLERANCE_PX * 1e-2, max_iter=_NEWTON_MAX_ITER, scale=max(self.fx, self.fy)
        )
        fx_, fy_ = self.distort_normalized(x, y)
        residual = float(np.max(np.hypot((fx_ - xd) * self.fx, (fy_ - yd) * self.fy))) if x.size else 0.0
        a, b, d = distortion_jacobian(x, y, self.dist)
        if not np.isfinite(residual) or residual > RAY_MAP_TOLERANCE_PX or np.any(a * d - b * b <= 0.0):
            raise DistortionNotInvertible(
                f"the distortion model (k1={self.k1}, k2={self.k2}, k3={self.k3}, p1={self.p1}, "
                f"p2={self.p2}) cannot be inverted over the image (residual {residual:.3g} px): it folds "
                "over inside the field of view; check the coefficients and their order (k1, k2, p1, p2, k3)"
            )
        return x, y, residual

    def undistort_pixels(self, uv: ArrayLike) -> F64:
        """Undistorted normalised coordinates (N, 2) of pixel positions (N, 2)."""
        P = np.atleast_2d(np.asarray(uv, dtype=float))
        if P.ndim != 2 or P.shape[1] != 2 or not np.all(np.isfinite(P)):
            raise ValueError(f"pixel positions must be finite with shape (N, 2), got {np.shape(uv)}")
        x, y, _ = self.undistort_normalized((P[:, 0] - self.cx) / self.fx, (P[:, 1] - self.cy) / self.fy)
        return np.column_stack([x, y])

    def ideal_pixels(self, uv: ArrayLike) -> F64:
        """Where pixel positions would lie without distortion (same camera matrix A)."""
        xy = self.undistort_pixels(uv)
        return np.column_stack([self.fx * xy[:, 0] + self.cx, self.fy * xy[:, 1] + self.cy])

    def ray_map(self, rows: int | None = None, cols: int | None = None) -> RayMap:
        """The cached ray map of ``rows`` x ``cols`` pixel centres (default: the image)."""
        return ray_map(self.intrinsics, rows or self.height, cols or self.width)


_CACHE: dict[tuple[object, ...], RayMap] = {}
_CACHE_LOCK = threading.Lock()
_CACHE_MAX = 4


def ray_map(intrinsics: CameraIntrinsics, rows: int, cols: int) -> RayMap:
    """Rays through the pixel centres (u, v) = (j, i), i < rows, j < cols; computed once and cached.

    Newton's method on each pixel in float64, started from the distorted coordinates; every ray
    re-distorts onto its pixel within RAY_MAP_TOLERANCE_PX (the achieved worst case is recorded).
    A request that fits inside a cached map for the same intrinsics is served as a view of it.
    """
    if rows <= 0 or cols <= 0:
        raise ValueError(f"ray map size must be positive, got {rows} x {cols}")
    key = tuple(intrinsics.model_dump().values())
    with _CACHE_LOCK:
        hit = _CACHE.get(key)
        if hit is None or hit.x.shape[0] < rows or hit.x.shape[1] < cols:
            # Compute at least the image padded to whole 16 px blocks plus one row and column, the
            # renderer's need, so one map serves every user of these intrinsics.
            need_r = max(rows, -(-intrinsics.height_px // 16) * 16 + 1)
            need_c = max(cols, -(-intrinsics.width_px // 16) * 16 + 1)
            if hit is not None:
                need_r, need_c = max(need_r, hit.x.shape[0]), max(need_c, hit.x.shape[1])
            hit = _compute_ray_map(CameraModel(intrinsics), need_r, need_c)
            _CACHE.pop(key, None)
            if len(_CACHE) >= _CACHE_MAX:
                _CACHE.pop(next(iter(_CACHE)))
            _CACHE[key] = hit
    return RayMap(hit.x[:rows, :cols], hit.y[:rows, :cols], hit.max_residual_px)


def _compute_ray_map(model: CameraModel, rows: int, cols: int) -> RayMap:
    u = np.arange(cols, dtype=np.float64)
    xd_row = (u - model.cx) / model.fx
    x = np.empty((rows, cols), dtype=np.float64)
    y = np.empty((rows, cols), dtype=np.float64)
    residual = 0.0
    chunk = max(1, 65536 // cols)  # rows per pass: small arrays stay in the CPU cache
    for r0 in range(0, rows, chunk):
        r1 = min(rows, r0 + chunk)
        yd = ((np.arange(r0, r1, dtype=np.float64) - model.cy) / model.fy)[:, None]
        xs, ys, res = model.undistort_normalized(
            np.broadcast_to(xd_row, (r1 - r0, cols)), np.broadcast_to(yd, (r1 - r0, cols))
        )
        x[r0:r1], y[r0:r1] = xs, ys
        residual = max(residual, res)
    x.setflags(write=False)
    y.setflags(write=False)
    return RayMap(x, y, residual)
