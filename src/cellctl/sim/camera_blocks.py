"""The twin camera's image geometry: where pixel rays meet a plane, and the image cut into blocks.

See cellctl.sim.camera (band rendering): blocks far from every edge are filled with one level,
the others are shaded per pixel with the plane-from-pixel Jacobian.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.pose import invert_pose
from cellctl.sim.camera_model import RayMap
from cellctl.sim.surface import JacobianAt

F64 = NDArray[np.float64]

BLOCK_PX = 16
WALL_BLOCK_PX = 8  # the wall's many parallel edges are shaded in finer blocks (fewer pixels near them)
TARGET_BLOCK_PX = 8  # and a board's grid lines (at 16 px, a board view took 1.5 times as long)


@dataclass(frozen=True)
class PlaneView:
    """A plane z = 0 of frame F seen from the camera: R = rotation C->F, o = camera centre in F."""

    R: F64
    o: F64

    @classmethod
    def of(cls, T_B_F: F64, T_B_C: F64) -> PlaneView:
        T_F_C = invert_pose(T_B_F) @ T_B_C
        return cls(T_F_C[:3, :3].copy(), T_F_C[:3, 3].copy())

    def hit(self, x: F64, y: F64) -> tuple[F64, F64, NDArray[np.bool_]]:
        """Plane coordinates (X, Y) where the rays (x, y, 1) meet it, and whether they do (ahead)."""
        R, o = self.R, self.o
        wx = R[0, 0] * x + R[0, 1] * y + R[0, 2]
        wy = R[1, 0] * x + R[1, 1] * y + R[1, 2]
        wz = R[2, 0] * x + R[2, 1] * y + R[2, 2]
        valid = wz * o[2] < -1e-12 * (np.abs(wz) + 1.0)
        lam = np.where(valid, -o[2] / np.where(valid, wz, 1.0), 0.0)
        return o[0] + lam * wx, o[1] + lam * wy, valid


class Blocks:
    """The image cut into square blocks of ``block_px``, with the ray map padded to whole blocks plus one."""

    def __init__(self, rays: RayMap, height: int, width: int, block_px: int = BLOCK_PX) -> None:
        self.B = B = block_px
        self.nby = -(-height // B)
        self.nbx = -(-width // B)
        self.hp, self.wp = self.nby * B, self.nbx * B
        self.rays = rays
        self.ray_stride = rays.x.shape[1]
        self.rx = rays.x.ravel()
        self.ry = rays.y.ravel()
        di, dj = np.mgrid[0:B, 0:B]
        self.ray_offsets = (di * self.ray_stride + dj).ravel()
        self.img_offsets = (di * self.wp + dj).ravel()
        gi, gj = np.mgrid[0 : B + 1, 0 : B + 1]
        self.grid_offsets = (gi * self.ray_stride + gj).ravel()
        self.grid_pixels = (di * (B + 1) + dj).ravel()  # the pixels' places in a block's grid
        self.corner_x = rays.x[: self.hp + 1 : B, : self.wp + 1 : B]
        self.corner_y = rays.y[: self.hp + 1 : B, : self.wp + 1 : B]

    def footprint(
        self, plane: PlaneView, *, spectral: bool = False
    ) -> tuple[F64, F64, F64, F64, NDArray[np.bool_]]:
        """Per block: centre (X, Y) on the plane, footprint radius (mm), mm per px, all corners valid.

        mm per px bounds the mapping's stretch: its Frobenius norm or, with ``spectral``, its largest
        singular value (up to sqrt 2 tighter), from the block's corners with 5 % for its variation
        in the block.
        """
        X, Y, ok = plane.hit(self.corner_x, self.corner_y)
        cx = 0.25 * (X[:-1, :-1] + X[:-1, 1:] + X[1:, :-1] + X[1:, 1:])
        cy = 0.25 * (Y[:-1, :-1] + Y[:-1, 1:] + Y[1:, :-1] + Y[1:, 1:])
        if spectral:
            ex, ey, fx, fy = np.diff(X, axis=1), np.diff(Y, axis=1), np.diff(X, axis=0), np.diff(Y, axis=0)
            stretch = np.zeros_like(cx)
            for a, c in ((ex[:-1], ey[:-1]), (ex[1:], ey[1:])):  # the block's top and bottom sides
                for b, d in ((fx[:, :-1], fy[:, :-1]), (fx[:, 1:], fy[:, 1:])):  # its left and right
                    f2 = a * a + b * b + c * c + d * d
                    det = a * d - b * c
                    sv2 = 0.5 * (f2 + np.sqrt(np.maximum(f2 * f2 - 4.0 * det * det, 0.0)))
                    stretch = np.maximum(stretch, np.sqrt(sv2))
        else:
            du = np.hypot(np.diff(X, axis=1), np.diff(Y, axis=1))
            dv = np.hypot(np.diff(X, axis=0), np.diff(Y, axis=0))
            stretch = np.hypot(np.maximum(du[:-1, :], du[1:, :]), np.maximum(dv[:, :-1], dv[:, 1:]))
        scale = 1.05 * stretch / self.B
        radius = scale * (self.B / math.sqrt(2.0) + 1.0)
        valid = ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, :-1] & ok[1:, 1:]
        return cx, cy, radius, scale, valid

    def indices(self, bi: NDArray[np.intp], bj: NDArray[np.intp]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Flat ray-map and image indices of all pixels in the given blocks."""
        B = self.B
        ray_idx = ((bi * B) * self.ray_stride + bj * B)[:, None] + self.ray_offsets[None, :]
        img_idx = ((bi * B) * self.wp + bj * B)[:, None] + self.img_offsets[None, :]
        return ray_idx.ravel(), img_idx.ravel()

    def pixel_hits(
        self, plane: PlaneView, ray_idx: NDArray[np.intp]
    ) -> tuple[F64, F64, tuple[F64, F64, F64, F64], NDArray[np.bool_]]:
        """Plane hits of the pixel centres and the plane-from-pixel Jacobian (forward differences)."""
        X0, Y0, v0 = plane.hit(self.rx[ray_idx], self.ry[ray_idx])
        Xu, Yu, vu = plane.hit(self.rx[ray_idx + 1], self.ry[ray_idx + 1])
        Xv, Yv, vv = plane.hit(self.rx[ray_idx + self.ray_stride], self.ry[ray_idx + self.ray_stride])
        jac = (Xu - X0, Xv - X0, Yu - Y0, Yv - Y0)
        det = jac[0] * jac[3] - jac[1] * jac[2]
        valid = v0 & vu & vv & (np.abs(det) > 0.0)
        return X0, Y0, jac, valid

    def block_hits(
        self, plane: PlaneView, bi: NDArray[np.intp], bj: NDArray[np.intp]
    ) -> tuple[F64, F64, JacobianAt, NDArray[np.bool_]]:
        """As :meth:`pixel_hits` for all pixels of whole blocks, shaped (blocks, B * B), from one
        plane hit per ray of each block's (B + 1)^2 grid (the same values: neighbours share rays).
        The Jacobian comes as a function of flat pixel indices, evaluated only where needed; a
        pixel is valid when its ray and its neighbours' meet the plane."""
        B, G, n = self.B, self.B + 1, bi.size
        ray_idx = ((bi * B) * self.ray_stride + bj * B)[:, None] + self.grid_offsets[None, :]
        X, Y, v = plane.hit(self.rx[ray_idx], self.ry[ray_idx])
        X, Y, v = X.ravel(), Y.ravel(), v.ravel()
        pixel = (np.arange(n)[:, None] * (G * G) + self.grid_pixels[None, :]).ravel()
        valid = (v[pixel] & v[pixel + 1] & v[pixel + G]).reshape(n, B * B)

        def jac_at(idx: NDArray[np.intp]) -> tuple[F64, F64, F64, F64]:
            g = pixel[idx]
            x0, y0 = X[g], Y[g]
            return X[g + 1] - x0, X[g + G] - x0, Y[g + 1] - y0, Y[g + G] - y0

        return X[pixel].reshape(n, B * B), Y[pixel].reshape(n, B * B), jac_at, valid
