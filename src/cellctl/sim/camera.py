"""The twin's camera: renders the car-body wall with its window opening, and calibration targets.

Scene: a mid-grey wall lit by a ring light beside the camera (``wall_dn``), the dark car interior
through the opening (``opening_dn``), the drawn surface of a real opening around its edge
(cellctl.sim.surface, one per car body), and targets (cellctl.sim.targets). Per frame:

1. Geometry: each pixel centre's ray (camera_model.ray_map, cached) meets the wall or a target plane.
2. Shading: the scene convolved with the optics' Gaussian (``blur_sigma_px``, ``defocus_sigma_px``
   in quadrature) over each pixel's square footprint, exact for straight edges as a function of
   the signed distance (edge_coverage), plane mm turned into px by each pixel's Jacobian.
3. Blocks of 8 x 8 px (camera_blocks' WALL_BLOCK_PX, TARGET_BLOCK_PX) farther from every edge than their
   footprint plus the kernel's reach are filled with one level; only blocks near edges are shaded per pixel, to
   within 1e-9 of the contrast of full per-pixel shading (camera_blocks).
4. Lighting: vignetting cos^``vignetting_power`` of the field angle, a linear gradient, glare.
5. Sensor: shot noise (Poisson, its normal approximation above 100 e-), read noise, black level,
   rounding and clipping to 8 bits.

Disturbances are drawn from the frame's rng (camera_disturbances) and reported in
:class:`AppliedDisturbances` with the drawn surface.

An installed glass (cellctl.sim.glass) lies over the wall: its plane is met by every ray on its
own, its edge and the frit's inner border are shaded like the wall's edges, and inside the
opening's edge only the gap's bottom shows. Frames without a glass take none of these steps.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Sequence, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.config.mounting import CameraIntrinsics
from cellctl.config.render import RenderConfig
from cellctl.geometry.pose import check_pose
from cellctl.sim.camera_blocks import BLOCK_PX, TARGET_BLOCK_PX, WALL_BLOCK_PX, Blocks, PlaneView
from cellctl.sim.camera_disturbances import Occluder, add_glare, plan_occlusion
from cellctl.sim.camera_model import CameraModel, ray_map
from cellctl.sim.edge_coverage import coverage_from_sdf, kernel_reach_px, rounded_rect_sdf
from cellctl.sim.glass import InstalledGlass
from cellctl.sim.image_truth import EdgeName
from cellctl.sim.surface import DrawnSurface, draw_surface
from cellctl.sim.targets import PlacedTarget
from cellctl.sim.world import World

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]
_G = TypeVar("_G", bound=np.generic)

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
        surface: the car body's surface as drawn in the frame (levels after the contrast factor);
            None when no car body is rendered.
        glass: the installed glass as drawn (levels after the contrast factor), if any.
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
    surface: DrawnSurface | None = None
    glass: InstalledGlass | None = None


@dataclass(frozen=True)
class RenderedFrame:
    """An 8-bit image and what was applied to it."""

    image: NDArray[np.uint8]
    applied: AppliedDisturbances


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
        self._blocks = Blocks(ray_map(intrinsics, hp + 1, wp + 1), hp, wp)
        self._wall_blocks = Blocks(self._blocks.rays, hp, wp, WALL_BLOCK_PX)
        self._target_blocks = Blocks(self._blocks.rays, hp, wp, TARGET_BLOCK_PX)
        self._illumination = self._illumination_field()
        self._surfaces: dict[tuple[int, float, float, float], DrawnSurface] = {}
        self._surfaces_lock = threading.Lock()

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
        glass: InstalledGlass | None = None,
    ) -> RenderedFrame:
        """One 8-bit frame seen from camera pose ``T_B_C``.

        ``world`` None renders no car body (a dark background), e.g. for calibration targets.
        ``rng`` drives the sensor noise and the placement of disturbances; it is required when
        either is in play. ``noise=False`` leaves out shot and read noise (rounding stays).
        ``glass`` is a glass installed in the car body's opening (it needs ``world``).
        """
        signal, applied = self._signal(T_B_C, world, targets, rng, noise, glass)
        image = self.expose(signal, rng, noise=noise)
        return RenderedFrame(self._sensor_crop(image), applied)

    def render_signal(
        self,
        T_B_C: ArrayLike,
        world: World | None,
        *,
        targets: Sequence[PlacedTarget] = (),
        rng: np.random.Generator | None = None,
        glass: InstalledGlass | None = None,
    ) -> tuple[F32, AppliedDisturbances]:
        """The noise-free, unquantised image (DN above the black level, float32) and the disturbances."""
        signal, applied = self._signal(T_B_C, world, targets, rng, False, glass)
        return self._sensor_crop(signal), applied

    def _sensor_crop(self, image: NDArray[_G]) -> NDArray[_G]:
        """The sensor's pixels of a rendered array (rendering runs on whole blocks, a little larger)."""
        return np.ascontiguousarray(image[: self.intrinsics.height_px, : self.intrinsics.width_px])

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
        glass: InstalledGlass | None = None,
    ) -> tuple[F32, AppliedDisturbances]:
        T = check_pose(T_B_C, "T_B_C")
        if world is not None and not isinstance(world, World):
            raise TypeError(f"world must be a cellctl.sim.world.World or None, got {type(world).__name__}")
        if glass is not None and (world is None or not isinstance(glass, InstalledGlass)):
            raise ValueError("a glass is drawn in its car body's opening: pass the world with an InstalledGlass")
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
        applied: dict[str, object] = {
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
            occluder = None
            if dist.occlusion is not None:
                assert rng is not None
                occluder = plan_occlusion(dist.occlusion, self.camera, T, world, rng, wall, opening, applied)
            surface = self.surface_of(world)
            applied["surface"] = surface
            if glass is not None:
                glass = glass.with_contrast(dist.contrast_factor, mean)
                applied["glass"] = glass
            self._shade_wall(albedo, T, surface, world, sigma, occluder, glass)
        for placed in targets:
            self._shade_target(albedo, T, placed, sigma)

        signal = albedo
        np.multiply(signal, self._illumination, out=signal)
        if world is not None and dist.glare is not None:
            assert rng is not None
            add_glare(dist.glare, self.camera, signal, T, world, rng, applied)
        return signal, AppliedDisturbances(**applied)  # type: ignore[arg-type]

    def surface_of(self, world: World) -> DrawnSurface:
        """The car body's surface as this renderer draws it (levels after the contrast factor), cached."""
        key = (world.surface_seed, world.width_mm, world.height_mm, world.corner_radius_mm)
        with self._surfaces_lock:
            hit = self._surfaces.get(key)
            if hit is None:
                cfg = self.config
                drawn = draw_surface(cfg.surface, key[0], world, wall_dn=cfg.wall_dn, opening_dn=cfg.opening_dn)
                hit = drawn.with_contrast(cfg.disturbances.contrast_factor)
                if len(self._surfaces) >= 16:
                    self._surfaces.pop(next(iter(self._surfaces)))
                self._surfaces[key] = hit
            return hit

    def _shade_wall(
        self,
        albedo: F32,
        T_B_C: F64,
        surface: DrawnSurface,
        world: World,
        sigma: float,
        occluder: Occluder | None,
        glass: InstalledGlass | None = None,
    ) -> None:
        blocks = self._wall_blocks
        plane = PlaneView.of(world.T_B_T, T_B_C)
        bx, by, radius, scale, valid = blocks.footprint(plane, spectral=True)
        reach_px = kernel_reach_px(sigma)
        margin = radius + reach_px * scale
        if glass is not None:
            surface = glass.glaze(surface)
        plan = surface.plan_blocks(bx, by, margin)
        level, edgy, near = plan.level, plan.edgy, list(plan.near)
        # Without band rendering, and in blocks whose footprint is unknown, every edge is shaded in
        # every pixel.
        everywhere = ~valid if self.band_rendering else np.ones_like(valid)
        edgy = edgy | everywhere
        if glass is not None:
            gplane = PlaneView.of(glass.T_B_G, T_B_C)
            gx, gy, g_radius, g_scale, g_valid = blocks.footprint(gplane, spectral=True)
            gplan = glass.plan_blocks(gx, gy, g_radius + reach_px * g_scale, g_valid)
            level = np.where(gplan.covered, gplan.level, level)
            # A block wholly on the glass needs per-pixel shading only where the frit's border crosses it.
            edgy = np.where(gplan.covered & ~everywhere, gplan.frit_edge, edgy | gplan.touch)
        if occluder is not None:
            sd_occ, _, _ = rounded_rect_sdf(bx, by, occluder[0], occluder[1], 0.0)
            level = np.where(sd_occ < 0.0, occluder[2], level)
            edgy |= np.abs(sd_occ) <= margin
            near.append(sd_occ <= margin)
        B = blocks.B
        albedo4 = albedo.reshape(blocks.nby, B, blocks.nbx, B)
        albedo4[...] = level.astype(np.float32)[:, None, :, None]
        bi, bj = np.nonzero(edgy)
        if bi.size == 0:
            return
        rows = [mask[bi, bj] | everywhere[bi, bj] for mask in near]
        X, Y, jac_at, ok = blocks.block_hits(plane, bi, bj)
        # Per pixel, a step's coverage is 0 or 1 beyond the kernel's reach; scale bounds mm per px.
        reach_mm = np.where(everywhere[bi, bj], np.inf, reach_px * scale[bi, bj])[:, None]
        shade = surface.shade(X, Y, jac_at, sigma, reach_mm=reach_mm, near=rows[: len(surface.overlays)])
        if glass is not None:
            g_rows = np.flatnonzero(gplan.touch[bi, bj] | gplan.covered[bi, bj] | everywhere[bi, bj])
            if g_rows.size:
                Xg, Yg, g_jac_at, g_ok = blocks.block_hits(gplane, bi[g_rows], bj[g_rows])
                g_reach = np.where(everywhere[bi, bj], np.inf, reach_px * g_scale[bi, bj])[g_rows, None]
                part = np.ascontiguousarray(shade[g_rows])
                glass.composite(part, Xg, Yg, g_jac_at, g_ok, sigma, g_reach)
                shade[g_rows] = part
        if occluder is not None:
            idx = (np.flatnonzero(rows[-1])[:, None] * (B * B) + np.arange(B * B)[None, :]).ravel()
            sd, gx, gy = rounded_rect_sdf(X.reshape(-1)[idx], Y.reshape(-1)[idx], occluder[0], occluder[1], 0.0)
            flat = shade.reshape(-1)  # a view: shade is contiguous
            part = flat[idx]
            part += (occluder[2] - part) * coverage_from_sdf(sd, gx, gy, jac_at(idx), sigma)
            flat[idx] = part
        shade = np.where(ok, shade, self.config.opening_dn)
        albedo4[bi, :, bj, :] = shade.reshape(bi.size, B, B)

    def _shade_target(self, albedo: F32, T_B_C: F64, placed: PlacedTarget, sigma: float) -> None:
        blocks = self._target_blocks
        plane = PlaneView.of(placed.T_B_P, T_B_C)
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
        # Blocks wholly on the plate, clear of its outline (covered, as shading each pixel gives), and of every printed
        # edge too take one printed level.
        on_plate = valid & (sd_plate < -margin) & self.band_rendering
        flat_print, level = placed.target.uniform_level(bx, by, margin)
        solid = on_plate & flat_print
        si, sj = np.nonzero(solid)
        if si.size:
            albedo.reshape(blocks.nby, blocks.B, blocks.nbx, blocks.B)[si, :, sj, :] = level[si, sj].astype(np.float32)[
                :, None, None
            ]
        bi, bj = np.nonzero(near & ~solid)
        if bi.size == 0:
            return
        ray_idx, img_idx = blocks.indices(bi, bj)
        Xp, Yp, jac, hit = blocks.pixel_hits(plane, ray_idx)
        covered = np.repeat(on_plate[bi, bj], blocks.B**2)
        cover = covered.astype(np.float64)
        if not np.all(covered):
            rim = ~covered
            sd, gx, gy = placed.plate_sdf(Xp[rim], Yp[rim])
            cover[rim] = coverage_from_sdf(sd, gx, gy, tuple(j[rim] for j in jac), sigma)  # type: ignore[arg-type]
        cover = np.where(hit, cover, 0.0)
        inside = cover > 0.0
        if not np.any(inside):
            return
        flat = albedo.reshape(-1)
        behind = flat[img_idx[inside]].astype(np.float64)
        jac_in = tuple(j[inside] for j in jac)
        printed = placed.target.shade(Xp[inside], Yp[inside], jac_in, sigma)  # type: ignore[arg-type]
        c = cover[inside]
        flat[img_idx[inside]] = behind + (printed - behind) * c

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
