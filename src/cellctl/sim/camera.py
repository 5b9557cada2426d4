"""The twin's camera: renders the car-body wall with its window opening, and calibration targets.

The scene, as decided for the twin: the car body is painted mid grey and lit by a ring light beside
the camera, so the wall is bright and even (``wall_dn``); through the opening the camera looks into
the unlit car interior, which is dark (``opening_dn``). Targets (cellctl.sim.targets) are printed
plates in front of the wall or stuck on it.

Image formation, per frame:

1. Geometry. Each pixel centre's ray (camera_model.ray_map, the inverse of the distortion, cached)
   meets the wall plane (a homography of the undistorted ray) or a target's plane.
2. Shading with analytic anti-aliasing. A pixel's value is the scene convolved with the optics'
   Gaussian blur (``blur_sigma_px``, with ``defocus_sigma_px`` added in quadrature) and integrated
   over its square footprint; near an edge that is a function of the signed distance to the edge,
   computed exactly for straight edges (edge_coverage). The plane distance is turned into pixels
   with the plane-from-pixel Jacobian of each pixel (finite differences of neighbouring rays).
3. Band rendering. The image is cut into 16 x 16 px blocks. For each block the wall position of its
   centre and a bound on its footprint's radius on the wall (mm) are computed from the rays at the
   block corners; a signed-distance function is 1-Lipschitz, so a block whose centre lies farther
   from every edge than that radius plus the blur kernel's reach (6 sigma + half a pixel diagonal,
   beyond which the coverage is 0 or 1 to within 1e-9 of the contrast) is uniform and is filled
   with its level. Only blocks near edges are shaded per pixel: the result equals per-pixel
   shading of the whole frame to within 1e-9 of the contrast.
4. Lighting: natural vignetting, cos(field angle)^``vignetting_power`` computed from the true rays,
   times a linear gradient across the image (uneven lighting); a glare spot is added on top.
5. Sensor: shot noise (Poisson; for counts above 100 electrons its normal approximation, whose
   error is far below one grey level), read noise, black level, rounding and clipping to 8 bits.

Disturbances (RenderConfig.disturbances) are drawn from the frame's rng and reported in
:class:`AppliedDisturbances`, so tests know what was done to an image.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.config.mounting import CameraIntrinsics
from cellctl.config.render import RenderConfig
from cellctl.geometry.pose import check_pose, invert_pose
from cellctl.sim.camera_model import CameraModel, RayMap, ray_map
from cellctl.sim.edge_coverage import coverage_from_sdf, kernel_reach_px, rounded_rect_sdf
from cellctl.sim.image_truth import EDGES, EdgeName, edge_curve_px, visible_edge_interval
from cellctl.sim.targets import PlacedTarget
from cellctl.sim.world import World

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]

BLOCK_PX = 16
# Below this many expected electrons a pixel's shot noise is drawn from the exact Poisson law.
POISSON_EXACT_BELOW_E = 100.0


@dataclass(frozen=True)
class AppliedDisturbances:
    """What was done to one frame beyond the clean scene.

    Attributes:
        blur_sigma_px: the effective Gaussian blur (optics and defocus in quadrature).
        contrast_factor: the wall-opening contrast scale.
        wall_dn, opening_dn: the levels used (after the contrast factor), at full illumination.
        glare_center_px, glare_peak_dn, glare_sigma_px: the glare spot, if any.
        occluded_edge: the edge ("top" or "right") partly covered, if any.
        occluded_span_mm: the along-edge range (mm from the virtual corner, see image_truth).
        occluder_dn: the occluder's level.
    """

    blur_sigma_px: float
    contrast_factor: float
    wall_dn: float
    opening_dn: float
    glare_center_px: tuple[float, float] | None = None
    glare_peak_dn: float | None = None
    glare_sigma_px: float | None = None
    occluded_edge: EdgeName | None = None
    occluded_span_mm: tuple[float, float] | None = None
    occluder_dn: float | None = None


@dataclass(frozen=True)
class RenderedFrame:
    """An 8-bit image and what was applied to it."""

    image: NDArray[np.uint8]
    applied: AppliedDisturbances


@dataclass(frozen=True)
class _PlaneView:
    """A plane z = 0 of frame F seen from the camera: R = rotation C->F, o = camera centre in F."""

    R: F64
    o: F64

    @classmethod
    def of(cls, T_B_F: F64, T_B_C: F64) -> "_PlaneView":
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


class _Blocks:
    """The image cut into BLOCK_PX blocks, with the ray map padded to whole blocks plus one."""

    def __init__(self, rays: RayMap, height: int, width: int) -> None:
        B = BLOCK_PX
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
        self.corner_x = rays.x[: self.hp + 1 : B, : self.wp + 1 : B]
        self.corner_y = rays.y[: self.hp + 1 : B, : self.wp + 1 : B]

    def footprint(self, plane: _PlaneView) -> tuple[F64, F64, F64, F64, NDArray[np.bool_]]:
        """Per block: centre (X, Y) on the plane, footprint radius (mm), mm per px, all corners valid."""
        X, Y, ok = plane.hit(self.corner_x, self.corner_y)
        cx = 0.25 * (X[:-1, :-1] + X[:-1, 1:] + X[1:, :-1] + X[1:, 1:])
        cy = 0.25 * (Y[:-1, :-1] + Y[:-1, 1:] + Y[1:, :-1] + Y[1:, 1:])
        du = np.hypot(np.diff(X, axis=1), np.diff(Y, axis=1))
        dv = np.hypot(np.diff(X, axis=0), np.diff(Y, axis=0))
        su = np.maximum(du[:-1, :], du[1:, :])
        sv = np.maximum(dv[:, :-1], dv[:, 1:])
        # Frobenius bound on the mapping's stretch (mm/px), with 5 % for its variation in the block.
        scale = 1.05 * np.hypot(su, sv) / BLOCK_PX
        radius = scale * (BLOCK_PX / math.sqrt(2.0) + 1.0)
        valid = ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, :-1] & ok[1:, 1:]
        return cx, cy, radius, scale, valid

    def indices(self, bi: NDArray[np.intp], bj: NDArray[np.intp]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Flat ray-map and image indices of all pixels in the given blocks."""
        B = BLOCK_PX
        ray_idx = ((bi * B) * self.ray_stride + bj * B)[:, None] + self.ray_offsets[None, :]
        img_idx = ((bi * B) * self.wp + bj * B)[:, None] + self.img_offsets[None, :]
        return ray_idx.ravel(), img_idx.ravel()

    def pixel_hits(
        self, plane: _PlaneView, ray_idx: NDArray[np.intp]
    ) -> tuple[F64, F64, tuple[F64, F64, F64, F64], NDArray[np.bool_]]:
        """Plane hits of the pixel centres and the plane-from-pixel Jacobian (forward differences)."""
        X0, Y0, v0 = plane.hit(self.rx[ray_idx], self.ry[ray_idx])
        Xu, Yu, vu = plane.hit(self.rx[ray_idx + 1], self.ry[ray_idx + 1])
        Xv, Yv, vv = plane.hit(self.rx[ray_idx + self.ray_stride], self.ry[ray_idx + self.ray_stride])
        jac = (Xu - X0, Xv - X0, Yu - Y0, Yv - Y0)
        det = jac[0] * jac[3] - jac[1] * jac[2]
        valid = v0 & vu & vv & (np.abs(det) > 0.0)
        return X0, Y0, jac, valid


_ILLUMINATION: dict[tuple[object, ...], F32] = {}
_ILLUMINATION_LOCK = threading.Lock()


class CameraRenderer:
    """Renders 8-bit mono frames of the twin's scene from any camera pose T_B_C."""

    def __init__(self, intrinsics: CameraIntrinsics, config: RenderConfig, *, band_rendering: bool = True) -> None:
        """``band_rendering`` False shades every pixel of the wall one by one (slow); it exists
        to check that the band rendering gives the same image."""
        self.intrinsics = intrinsics
        self.config = config
        self.band_rendering = band_rendering
        self.camera = CameraModel(intrinsics)
        B = BLOCK_PX
        hp = -(-intrinsics.height_px // B) * B
        wp = -(-intrinsics.width_px // B) * B
        self._blocks = _Blocks(ray_map(intrinsics, hp + 1, wp + 1), intrinsics.height_px, intrinsics.width_px)
        self._illumination = self._illumination_field()

    @property
    def ray_map_residual_px(self) -> float:
        """Worst distance (px) between a pixel and its cached ray distorted again."""
        return self._blocks.rays.max_residual_px

    # --- public API ----------------------------------------------------------------------------

    def render(
        self,
        T_B_C: ArrayLike,
        world: World | None,
        *,
        targets: Sequence[PlacedTarget] = (),
        rng: np.random.Generator | None = None,
        noise: bool = True,
    ) -> RenderedFrame:
        """One 8-bit frame seen from camera pose ``T_B_C``.

        ``world`` None renders no car body (a dark background), e.g. for calibration targets.
        ``rng`` drives the sensor noise and the placement of disturbances; it is required when
        either is in play. ``noise=False`` leaves out shot and read noise (rounding stays).
        """
        signal, applied = self._signal(T_B_C, world, targets, rng, noise)
        image = self.expose(signal, rng, noise=noise)
        return RenderedFrame(
            np.ascontiguousarray(image[: self.intrinsics.height_px, : self.intrinsics.width_px]), applied
        )

    def render_signal(
        self,
        T_B_C: ArrayLike,
        world: World | None,
        *,
        targets: Sequence[PlacedTarget] = (),
        rng: np.random.Generator | None = None,
    ) -> tuple[F32, AppliedDisturbances]:
        """The noise-free, unquantised image (DN above the black level, float32) and the disturbances."""
        signal, applied = self._signal(T_B_C, world, targets, rng, False)
        return np.ascontiguousarray(signal[: self.intrinsics.height_px, : self.intrinsics.width_px]), applied

    def project(self, points_B: ArrayLike, T_B_C: ArrayLike) -> F64:
        """Pixel coordinates (N, 2), with distortion, of points in the base frame (cv2.projectPoints' model)."""
        return self.camera.project(points_B, T_B_C)

    # --- the pipeline ---------------------------------------------------------------------------

    def _signal(
        self,
        T_B_C: ArrayLike,
        world: World | None,
        targets: Sequence[PlacedTarget],
        rng: np.random.Generator | None,
        noise: bool,
    ) -> tuple[F32, AppliedDisturbances]:
        T = check_pose(T_B_C, "T_B_C")
        if world is not None and not isinstance(world, World):
            raise TypeError(f"world must be a cellctl.sim.world.World or None, got {type(world).__name__}")
        cfg = self.config
        dist = cfg.disturbances
        needs_rng = noise and (cfg.read_noise_dn > 0 or cfg.shot_noise)
        needs_rng |= world is not None and (dist.glare is not None or dist.occlusion is not None)
        if needs_rng and rng is None:
            raise ValueError("this render draws noise or disturbance placements: pass a seeded numpy Generator as rng")
        sigma = math.hypot(cfg.blur_sigma_px, dist.defocus_sigma_px)
        mean = 0.5 * (cfg.wall_dn + cfg.opening_dn)
        wall = mean + dist.contrast_factor * (cfg.wall_dn - mean)
        opening = mean + dist.contrast_factor * (cfg.opening_dn - mean)
        applied = {
            "blur_sigma_px": sigma,
            "contrast_factor": dist.contrast_factor,
            "wall_dn": wall,
            "opening_dn": opening,
        }

        blocks = self._blocks
        albedo = np.empty((blocks.hp, blocks.wp), dtype=np.float32)
        if world is None:
            albedo.fill(cfg.opening_dn)
        else:
            occluder = self._plan_occlusion(T, world, rng, wall, opening, applied)
            self._shade_wall(albedo, T, world, sigma, wall, opening, occluder)
        for placed in targets:
            self._shade_target(albedo, T, placed, sigma)

        signal = albedo
        np.multiply(signal, self._illumination, out=signal)
        if world is not None and dist.glare is not None:
            assert rng is not None
            self._add_glare(signal, T, world, rng, applied)
        return signal, AppliedDisturbances(**applied)

    def _shade_wall(
        self,
        albedo: F32,
        T_B_C: F64,
        world: World,
        sigma: float,
        wall: float,
        opening: float,
        occluder: tuple[tuple[float, float], tuple[float, float], float] | None,
    ) -> None:
        blocks = self._blocks
        plane = _PlaneView.of(world.T_B_T, T_B_C)
        centre = (-world.width_mm / 2.0, world.height_mm / 2.0)
        half = (world.width_mm / 2.0, world.height_mm / 2.0)
        r = world.corner_radius_mm
        bx, by, radius, scale, valid = blocks.footprint(plane)
        margin = radius + kernel_reach_px(sigma) * scale
        sd_open, _, _ = rounded_rect_sdf(bx, by, centre, half, r)
        level = np.where(sd_open < 0.0, opening, wall)
        edgy = ~valid | (np.abs(sd_open) <= margin) | (not self.band_rendering)
        if occluder is not None:
            sd_occ, _, _ = rounded_rect_sdf(bx, by, occluder[0], occluder[1], 0.0)
            level = np.where(sd_occ < 0.0, occluder[2], level)
            edgy |= np.abs(sd_occ) <= margin
        B = BLOCK_PX
        albedo.reshape(blocks.nby, B, blocks.nbx, B)[...] = level.astype(np.float32)[:, None, :, None]
        bi, bj = np.nonzero(edgy)
        if bi.size == 0:
            return
        ray_idx, img_idx = blocks.indices(bi, bj)
        X, Y, jac, ok = blocks.pixel_hits(plane, ray_idx)
        sd, gx, gy = rounded_rect_sdf(X, Y, centre, half, r)
        shade = wall + (opening - wall) * coverage_from_sdf(sd, gx, gy, jac, sigma)
        if occluder is not None:
            sd, gx, gy = rounded_rect_sdf(X, Y, occluder[0], occluder[1], 0.0)
            shade += (occluder[2] - shade) * coverage_from_sdf(sd, gx, gy, jac, sigma)
        shade = np.where(ok, shade, self.config.opening_dn)
        albedo.reshape(-1)[img_idx] = shade

    def _shade_target(self, albedo: F32, T_B_C: F64, placed: PlacedTarget, sigma: float) -> None:
        blocks = self._blocks
        plane = _PlaneView.of(placed.T_B_P, T_B_C)
        if plane.o[2] >= 0.0:
            raise ValueError(
                f"{placed.target.name}: the camera is behind the plate (T_B_P's z axis must point away "
                "from the camera, into the plate)"
            )
        bx, by, radius, scale, valid = blocks.footprint(plane)
        margin = radius + kernel_reach_px(sigma) * scale
        sd_plate, _, _ = placed.plate_sdf(bx, by)
        X, Y, ok = plane.hit(blocks.corner_x, blocks.corner_y)
        any_ok = ok[:-1, :-1] | ok[:-1, 1:] | ok[1:, :-1] | ok[1:, 1:]
        near = np.where(valid, sd_plate <= margin, any_ok)
        # Blocks wholly on the plate and clear of every printed edge take one printed level.
        flat_print, level = placed.target.uniform_level(bx, by, margin)
        solid = valid & (sd_plate < -margin) & flat_print & self.band_rendering
        si, sj = np.nonzero(solid)
        if si.size:
            albedo.reshape(blocks.nby, BLOCK_PX, blocks.nbx, BLOCK_PX)[si, :, sj, :] = level[si, sj].astype(np.float32)[
                :, None, None
            ]
        bi, bj = np.nonzero(near & ~solid)
        if bi.size == 0:
            return
        ray_idx, img_idx = blocks.indices(bi, bj)
        Xp, Yp, jac, hit = blocks.pixel_hits(plane, ray_idx)
        sd, gx, gy = placed.plate_sdf(Xp, Yp)
        cover = np.where(hit, coverage_from_sdf(sd, gx, gy, jac, sigma), 0.0)
        inside = cover > 0.0
        if not np.any(inside):
            return
        flat = albedo.reshape(-1)
        behind = flat[img_idx[inside]].astype(np.float64)
        jac_in = tuple(j[inside] for j in jac)
        printed = placed.target.shade(Xp[inside], Yp[inside], jac_in, sigma)  # type: ignore[arg-type]
        c = cover[inside]
        flat[img_idx[inside]] = behind + (printed - behind) * c

    def _plan_occlusion(
        self,
        T_B_C: F64,
        world: World,
        rng: np.random.Generator | None,
        wall: float,
        opening: float,
        applied: dict[str, object],
    ) -> tuple[tuple[float, float], tuple[float, float], float] | None:
        occ = self.config.disturbances.occlusion
        if occ is None:
            return None
        assert rng is not None
        intervals = {e: visible_edge_interval(self.camera, T_B_C, world, e) for e in EDGES}
        choices = [e for e in EDGES if intervals[e] is not None] if occ.edge == "random" else [occ.edge]
        draw = rng.random(2)  # always two draws, so later draws do not depend on visibility
        pick = min(int(draw[0] * len(choices)), len(choices) - 1) if choices else 0
        a_pick = float(draw[1])
        if not choices or intervals[choices[pick]] is None:
            return None
        edge = choices[pick]
        a0, a1 = intervals[edge]  # type: ignore[misc]
        length = occ.edge_fraction * (a1 - a0)
        start = a0 + a_pick * (a1 - a0 - length)
        mid = start + length / 2.0
        if edge == "top":
            centre, half = (-mid, 0.0), (length / 2.0, occ.width_mm / 2.0)
        else:
            centre, half = (0.0, mid), (occ.width_mm / 2.0, length / 2.0)
        level = wall if occ.kind == "wall_like" else opening
        applied.update(occluded_edge=edge, occluded_span_mm=(start, start + length), occluder_dn=level)
        return centre, half, level

    def _add_glare(
        self, signal: F32, T_B_C: F64, world: World, rng: np.random.Generator, applied: dict[str, object]
    ) -> None:
        glare = self.config.disturbances.glare
        assert glare is not None
        w, h = self.intrinsics.width_px, self.intrinsics.height_px
        centre: tuple[float, float] | None = None
        draw = rng.random(4)
        if glare.on_edge:
            intervals = [
                (e, iv) for e in EDGES if (iv := visible_edge_interval(self.camera, T_B_C, world, e)) is not None
            ]
            if intervals:
                edge, (a0, a1) = intervals[int(draw[0] * len(intervals)) % len(intervals)]
                uv = edge_curve_px(self.camera, T_B_C, world, edge, [a0 + draw[1] * (a1 - a0)])[0]
                offset = (draw[2:] - 0.5) * glare.sigma_px
                centre = (float(uv[0] + offset[0]), float(uv[1] + offset[1]))
        if centre is None:
            centre = (float(draw[2] * (w - 1)), float(draw[3] * (h - 1)))
        reach = 5.0 * glare.sigma_px
        u0, u1 = max(0, int(centre[0] - reach)), min(signal.shape[1], int(centre[0] + reach) + 1)
        v0, v1 = max(0, int(centre[1] - reach)), min(signal.shape[0], int(centre[1] + reach) + 1)
        if u1 > u0 and v1 > v0:
            gu = np.exp(-0.5 * ((np.arange(u0, u1) - centre[0]) / glare.sigma_px) ** 2).astype(np.float32)
            gv = np.exp(-0.5 * ((np.arange(v0, v1) - centre[1]) / glare.sigma_px) ** 2).astype(np.float32)
            signal[v0:v1, u0:u1] += np.float32(glare.peak_dn) * gv[:, None] * gu[None, :]
        applied.update(glare_center_px=centre, glare_peak_dn=glare.peak_dn, glare_sigma_px=glare.sigma_px)

    def expose(self, signal: F32, rng: np.random.Generator | None, *, noise: bool = True) -> NDArray[np.uint8]:
        """The sensor stage: shot and read noise, black level, rounding and 8-bit saturation.

        ``signal`` is a float32 image in DN above the black level (as from :meth:`render_signal`);
        it is overwritten. ``rng`` is required when ``noise`` is on.
        """
        cfg = self.config
        if signal.dtype != np.float32 or signal.ndim != 2:
            raise ValueError(f"signal must be a 2-D float32 image, got {signal.dtype} {signal.shape}")
        if noise and (cfg.shot_noise or cfg.read_noise_dn > 0) and rng is None:
            raise ValueError("sensor noise needs a seeded numpy Generator as rng")
        np.maximum(signal, 0.0, out=signal)
        if noise and (cfg.shot_noise or cfg.read_noise_dn > 0):
            assert rng is not None
            z = rng.standard_normal(signal.shape, dtype=np.float32)
            if cfg.shot_noise:
                gain = np.float32(1.0 / cfg.electrons_per_dn)
                sigma = signal * gain
                sigma += np.float32(cfg.read_noise_dn**2)
                np.sqrt(sigma, out=sigma)
                low = signal < np.float32(POISSON_EXACT_BELOW_E / cfg.electrons_per_dn)
                sigma *= z
                if np.any(low):
                    electrons = rng.poisson(signal[low].astype(np.float64) * cfg.electrons_per_dn)
                    sigma[low] = (electrons / cfg.electrons_per_dn - signal[low] + cfg.read_noise_dn * z[low]).astype(
                        np.float32
                    )
                signal += sigma
            else:
                z *= np.float32(cfg.read_noise_dn)
                signal += z
        signal += np.float32(cfg.black_level_dn + 0.5)
        np.clip(signal, 0.0, 255.0, out=signal)
        return signal.astype(np.uint8)

    def _illumination_field(self) -> F32:
        """Vignetting cos^p(field angle) times the linear lighting gradient, per pixel (cached)."""
        cfg = self.config
        key = (
            tuple(self.intrinsics.model_dump().values()),
            cfg.vignetting_power,
            cfg.lighting_gradient,
            cfg.lighting_gradient_angle_deg,
        )
        with _ILLUMINATION_LOCK:
            hit = _ILLUMINATION.get(key)
            if hit is not None:
                return hit
            blocks = self._blocks
            x = blocks.rays.x[: blocks.hp, : blocks.wp]
            y = blocks.rays.y[: blocks.hp, : blocks.wp]
            cos2 = 1.0 / (1.0 + x * x + y * y)
            field = cos2 ** (cfg.vignetting_power / 2.0)
            phi = math.radians(cfg.lighting_gradient_angle_deg)
            u = np.arange(blocks.wp) - self.intrinsics.cx
            v = np.arange(blocks.hp) - self.intrinsics.cy
            ramp = (
                1.0
                + cfg.lighting_gradient
                * (math.cos(phi) * u[None, :] + math.sin(phi) * v[:, None])
                / self.intrinsics.width_px
            )
            field = (field * ramp).astype(np.float32)
            field.setflags(write=False)
            if len(_ILLUMINATION) >= 4:
                _ILLUMINATION.pop(next(iter(_ILLUMINATION)))
            _ILLUMINATION[key] = field
            return field
