"""One car body's surface around its opening, drawn from cellctl.config.surface, and its shading.

:func:`draw_surface` turns the configured ranges into concrete widths, greys, marks and dirt for
one car body (a seed, see World.surface_seed). The result, :class:`DrawnSurface`, is a profile
across the edge plus small overlays:

- ``steps``: (offset_mm, level_dn) pairs from the wall side inwards. A step's border is the level
  set ``sd = offset`` of the opening's rounded-rectangle signed distance ``sd`` (negative inside
  the opening): an offset rounded rectangle whose normal is the gradient of ``sd``. Points with
  ``sd < offset`` take the step's level (beyond the previous steps); the wall (``wall_dn``) lies
  beyond the first. Offsets decrease strictly; the last level is the car interior.
- ``marks`` (rotated strips) and ``dirt`` (round spots) laid over the profile, in that order.

A pixel's value (see cellctl.sim.camera) is ``L0 + sum_k (L_k - L_k-1) * coverage(sd - o_k)``,
then ``shade += (level - shade) * coverage`` for every mark and spot. Coverage is only computed
where a border lies within the blur kernel's reach; elsewhere it is exactly 0 or 1.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from itertools import pairwise
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from cellctl.config.render import RenderConfig
from cellctl.config.surface import BandConfig, SurfaceConfig
from cellctl.sim.edge_coverage import circle_sdf, coverage_from_sdf, rounded_rect_sdf
from cellctl.sim.world import World

F64 = NDArray[np.float64]
Bool = NDArray[np.bool_]
Jacobian = tuple[F64, F64, F64, F64]
JacobianAt = Callable[[NDArray[np.intp]], Jacobian]
"""The plane-from-pixel Jacobian (dX/du, dX/dv, dY/du, dY/dv) at given flat pixel indices."""
Sdf = tuple[F64, F64, F64]
EdgeSide = Literal["top", "right"]


def _point_on_edge(edge: EdgeSide, along_mm: float, off_mm: float) -> tuple[float, float]:
    """T's (x, y) at ``along_mm`` from the virtual corner along an edge's line, ``off_mm`` off it
    (positive into the opening)."""
    if edge == "top":
        return (0.0 - along_mm, off_mm)
    return (0.0 - off_mm, along_mm)


@dataclass(frozen=True)
class Mark:
    """A thin strip crossing a straight edge, centred on it.

    Attributes:
        centre_mm: its centre (x, y) in T, on the edge's line.
        angle_rad: direction of its long axis in T's x-y plane, from +x towards +y.
        length_mm, width_mm: its size along and across that axis.
        level_dn: its grey (DN, not scaled by the contrast factor).
        edge, along_mm: the edge it crosses and the crossing's distance from the virtual corner.
    """

    centre_mm: tuple[float, float]
    angle_rad: float
    length_mm: float
    width_mm: float
    level_dn: float
    edge: EdgeSide
    along_mm: float

    def sdf(self, x: F64, y: F64) -> Sdf:
        """Signed distance (mm, negative inside) to the strip and its unit gradient in T."""
        c, s = math.cos(self.angle_rad), math.sin(self.angle_rad)
        dx = x - self.centre_mm[0]
        dy = y - self.centre_mm[1]
        d, gu, gv = rounded_rect_sdf(
            c * dx + s * dy, c * dy - s * dx, (0.0, 0.0), (self.length_mm / 2.0, self.width_mm / 2.0), 0.0
        )
        return d, c * gu - s * gv, s * gu + c * gv


@dataclass(frozen=True)
class DirtSpot:
    """A round spot of dirt: centre (x, y) in T (mm), radius (mm) and grey (DN, not contrast-scaled)."""

    centre_mm: tuple[float, float]
    radius_mm: float
    level_dn: float

    def sdf(self, x: F64, y: F64) -> Sdf:
        """Signed distance (mm, negative inside) to the spot and its unit gradient in T."""
        return circle_sdf(x, y, self.centre_mm[0], self.centre_mm[1], self.radius_mm)


@dataclass(frozen=True)
class BlockPlan:
    """Which image blocks the surface leaves uniform (see DrawnSurface.plan_blocks).

    Attributes:
        level: each block's level when uniform.
        edgy: blocks to shade per pixel (near a border).
        near: per overlay (marks, then dirt spots), the blocks it may touch (near or inside it).
    """

    level: F64
    edgy: Bool
    near: tuple[Bool, ...]


@dataclass(frozen=True)
class DrawnSurface:
    """The surface of one car body around its opening (module docstring).

    Attributes:
        steps: (offset_mm, level_dn) from the wall side inwards; offsets strictly decrease.
        marks, dirt: overlays, drawn in this order on top of the profile.
        wall_dn: the level beyond the first step.
        opening_centre_mm, opening_half_mm, corner_radius_mm: the opening's rounded rectangle in T.
    """

    steps: tuple[tuple[float, float], ...]
    marks: tuple[Mark, ...]
    dirt: tuple[DirtSpot, ...]
    wall_dn: float
    opening_centre_mm: tuple[float, float]
    opening_half_mm: tuple[float, float]
    corner_radius_mm: float

    def __post_init__(self) -> None:
        offsets = [o for o, _ in self.steps]
        if not offsets or any(b >= a for a, b in pairwise(offsets)):
            raise ValueError(f"steps need at least one offset and strictly decreasing offsets, got {offsets}")

    @property
    def opening_dn(self) -> float:
        """The car interior's level (the last step's)."""
        return self.steps[-1][1]

    @property
    def levels(self) -> tuple[float, ...]:
        """The plateau levels from the wall inwards: wall_dn, then each step's."""
        return (self.wall_dn, *(level for _, level in self.steps))

    @property
    def overlays(self) -> tuple[Mark | DirtSpot, ...]:
        """Marks then dirt spots, in drawing order."""
        return (*self.marks, *self.dirt)

    def opening_sdf(self, x: F64, y: F64) -> Sdf:
        """The opening's signed distance (mm, negative inside) and gradient at T points (x, y)."""
        return rounded_rect_sdf(x, y, self.opening_centre_mm, self.opening_half_mm, self.corner_radius_mm)

    def profile_level(self, sd: F64) -> F64:
        """The plateau level at signed distances ``sd`` from the opening's edge (no blur, no overlays)."""
        sd = np.asarray(sd, dtype=np.float64)
        index = np.zeros(sd.shape, dtype=np.intp)
        for offset, _ in self.steps:
            index += sd < offset
        return np.asarray(self.levels, dtype=np.float64)[index]

    def with_contrast(self, factor: float) -> DrawnSurface:
        """The profile's levels scaled by ``factor`` about the wall-interior mean (overlays keep theirs)."""
        mean = 0.5 * (self.wall_dn + self.opening_dn)
        steps = tuple((o, mean + factor * (level - mean)) for o, level in self.steps)
        return replace(self, steps=steps, wall_dn=mean + factor * (self.wall_dn - mean))

    def plan_blocks(self, bx: F64, by: F64, margin: F64) -> BlockPlan:
        """Classify blocks by their centre (bx, by) in T and footprint-plus-kernel ``margin`` (mm).

        A block is uniform when it lies farther than ``margin`` from every border (signed distances
        are 1-Lipschitz); its level is the profile's at its centre with the overlays it lies in.
        """
        sd = self.distance(bx, by)
        level = self.profile_level(sd)
        edgy = np.zeros(sd.shape, dtype=bool)
        for offset, _ in self.steps:
            edgy |= np.abs(sd - offset) <= margin
        near: list[Bool] = []
        for feature in self.overlays:
            d, _, _ = feature.sdf(bx, by)
            level = np.where(d < 0.0, feature.level_dn, level)
            edgy |= np.abs(d) <= margin
            near.append(d <= margin)  # and inside: an edgy block there takes the level per pixel
        return BlockPlan(level, edgy, tuple(near))

    def distance(self, x: F64, y: F64) -> F64:
        """The opening's signed distance alone (the same values as :meth:`opening_sdf`'s)."""
        (cx, cy), (hx, hy), r = self.opening_centre_mm, self.opening_half_mm, self.corner_radius_mm
        qx = np.abs(x - cx) - (hx - r)
        qy = np.abs(y - cy) - (hy - r)
        corner = (qx > 0.0) & (qy > 0.0)
        qn = np.sqrt(np.maximum(qx, 0.0) ** 2 + np.maximum(qy, 0.0) ** 2)
        return np.where(corner, qn, np.maximum(qx, qy)) - r

    def shade(
        self,
        x: F64,
        y: F64,
        jac: Jacobian | JacobianAt,
        sigma_px: float,
        *,
        reach_mm: F64 | None = None,
        near: Sequence[Bool] | None = None,
    ) -> F64:
        """Pixel values at T points (x, y) with plane-from-pixel Jacobian ``jac`` and blur ``sigma_px``.

        ``jac`` is four arrays shaped like ``x`` or a function giving them at flat indices of ``x``.
        ``reach_mm`` (broadcast to ``x``) bounds the kernel's reach in mm: a step's coverage is only
        computed within it of the step's border and is exactly 0 or 1 beyond. ``near`` (per overlay,
        over the first axis of ``x``) limits where each mark and spot is drawn. None computes every
        border everywhere.
        """
        shape = np.shape(x)
        xf, yf = np.ravel(x), np.ravel(y)
        if callable(jac):
            jac_at = jac
        else:
            flat: Jacobian = (np.ravel(jac[0]), np.ravel(jac[1]), np.ravel(jac[2]), np.ravel(jac[3]))
            jac_at = partial(_take, flat)
        d = self.distance(xf, yf)
        index = np.zeros(d.shape, dtype=np.intp)
        for offset, _ in self.steps:
            index += d < offset
        shade = np.asarray(self._plateaus(), dtype=np.float64)[index]
        reach = None if reach_mm is None else np.broadcast_to(reach_mm, shape).ravel()
        if reach is None:
            close: NDArray[np.intp] = np.arange(d.size)
        else:
            mask = np.zeros(d.shape, dtype=bool)
            for offset, _ in self.steps:
                mask |= np.abs(d - offset) <= reach
            close = np.flatnonzero(mask)
        if close.size:
            sd, gx, gy = self.opening_sdf(xf[close], yf[close])
            J = jac_at(close)
            value = np.full(close.size, self.wall_dn, dtype=np.float64)
            previous = self.wall_dn
            for offset, level in self.steps:
                if reach is None:
                    cover = coverage_from_sdf(sd - offset, gx, gy, J, sigma_px)
                else:
                    cover = (sd < offset).astype(np.float64)
                    k = np.flatnonzero(np.abs(sd - offset) <= reach[close])
                    cover[k] = coverage_from_sdf(sd[k] - offset, gx[k], gy[k], _take(J, k), sigma_px)
                value += (level - previous) * cover
                previous = level
            shade[close] = value
        per_row = int(np.prod(shape[1:], dtype=np.intp)) if len(shape) > 1 else 1
        for k, feature in enumerate(self.overlays):
            if near is None:
                idx: NDArray[np.intp] = np.arange(d.size)
            else:
                rows = np.flatnonzero(near[k])
                idx = (rows[:, None] * per_row + np.arange(per_row)[None, :]).ravel()
            if idx.size:
                df, fx, fy = feature.sdf(xf[idx], yf[idx])
                part = shade[idx]
                part += (feature.level_dn - part) * coverage_from_sdf(df, fx, fy, jac_at(idx), sigma_px)
                shade[idx] = part
        return shade.reshape(shape)

    def _plateaus(self) -> list[float]:
        """The profile's plateau values as the per-pixel sum makes them (coverages exactly 0 or 1)."""
        values = [self.wall_dn]
        previous = self.wall_dn
        for _, level in self.steps:
            values.append(values[-1] + (level - previous))
            previous = level
        return values


def _take(jac: Jacobian, idx: NDArray[np.intp]) -> Jacobian:
    return (jac[0][idx], jac[1][idx], jac[2][idx], jac[3][idx])


def _in(rng: np.random.Generator, low_high: tuple[float, float]) -> float:
    """A uniform draw in [low, high] (exactly low when they are equal); always one draw."""
    low, high = float(low_high[0]), float(low_high[1])
    return low + (high - low) * float(rng.random())


def _count(rng: np.random.Generator, low_high: tuple[int, int]) -> int:
    return int(rng.integers(low_high[0], low_high[1] + 1))


def _check_range(name: str, low_high: tuple[float, float]) -> None:
    if not low_high[0] <= low_high[1]:
        raise ValueError(f"{name} must be [low, high] with low <= high, got [{low_high[0]:g}, {low_high[1]:g}]")


def _check(config: SurfaceConfig) -> None:
    """Re-check the ranges (a model built with model_construct skips pydantic), naming the field."""
    for band_name in ("paint_band", "flange", "seal"):
        band: BandConfig | None = getattr(config, band_name)
        if band is not None:
            _check_range(f"surface.{band_name}.width_mm", band.width_mm)
            _check_range(f"surface.{band_name}.dn", band.dn)
    if config.marks is not None:
        for name in ("count", "width_mm", "length_mm", "angle_deg", "bright_dn", "dark_dn"):
            _check_range(f"surface.marks.{name}", getattr(config.marks, name))
    if config.dirt is not None:
        for name in ("count", "radius_mm", "dn"):
            _check_range(f"surface.dirt.{name}", getattr(config.dirt, name))


def draw_surface(
    config: SurfaceConfig,
    seed: int,
    world: World,
    *,
    wall_dn: float | None = None,
    opening_dn: float | None = None,
) -> DrawnSurface:
    """Draw one car body's surface from ``np.random.default_rng(seed)`` within ``config``'s ranges.

    The bands, the marks and the dirt each draw from their own child stream, and a band draws even
    when it is left out, so switching one part on or off does not change the others.
    ``wall_dn``/``opening_dn`` are the wall and interior levels (default: RenderConfig's).
    """
    _check(config)
    defaults = RenderConfig.model_fields
    wall = float(defaults["wall_dn"].default if wall_dn is None else wall_dn)
    interior = float(defaults["opening_dn"].default if opening_dn is None else opening_dn)
    band_rng, marks_rng, dirt_rng = np.random.default_rng(seed).spawn(3)

    drawn: dict[str, tuple[float, float] | None] = {}
    for band_name in ("paint_band", "flange", "seal"):
        band: BandConfig | None = getattr(config, band_name)
        width = _in(band_rng, band.width_mm if band else (0.0, 0.0))
        level = _in(band_rng, band.dn if band else (0.0, 0.0))
        drawn[band_name] = (width, level) if band is not None else None
    paint, flange, seal = drawn["paint_band"], drawn["flange"], drawn["seal"]
    depth = (flange[0] if flange else 0.0) + (seal[0] if seal else 0.0)
    if depth >= 0.5 * min(world.width_mm, world.height_mm):
        raise ValueError(
            f"surface.flange and surface.seal ({depth:g} mm together) do not fit inside the "
            f"{world.width_mm:g} x {world.height_mm:g} mm opening; narrow them"
        )
    # Inwards from the wall's edge: the flange, then the seal, then the interior.
    inner = [b for b in (flange, seal) if b is not None] + [(0.0, interior)]
    steps: list[tuple[float, float]] = [(paint[0], paint[1])] if paint is not None else []
    offset = 0.0
    for width, level in inner:
        steps.append((offset, level))
        offset -= width

    marks: list[Mark] = []
    if config.marks is not None:
        mc = config.marks
        for _ in range(_count(marks_rng, mc.count)):
            edge: EdgeSide = "top" if marks_rng.random() < 0.5 else "right"
            along = _in(marks_rng, (0.0, min(mc.within_mm, _edge_length(world, edge))))
            angle = math.radians(_in(marks_rng, mc.angle_deg)) + (0.0 if edge == "top" else math.pi / 2.0)
            length, width = _in(marks_rng, mc.length_mm), _in(marks_rng, mc.width_mm)
            bright = marks_rng.random() < 0.5 if mc.kind == "either" else mc.kind == "bright"
            level = _in(marks_rng, mc.bright_dn if bright else mc.dark_dn)
            marks.append(Mark(_point_on_edge(edge, along, 0.0), angle, length, width, level, edge, along))

    dirt: list[DirtSpot] = []
    if config.dirt is not None:
        dc = config.dirt
        for _ in range(_count(dirt_rng, dc.count)):
            edge = "top" if dirt_rng.random() < 0.5 else "right"
            along = _in(dirt_rng, (0.0, min(dc.within_mm, _edge_length(world, edge))))
            off = _in(dirt_rng, (-dc.spread_mm, dc.spread_mm))
            radius, level = _in(dirt_rng, dc.radius_mm), _in(dirt_rng, dc.dn)
            dirt.append(DirtSpot(_point_on_edge(edge, along, off), radius, level))

    return DrawnSurface(
        steps=tuple(steps),
        marks=tuple(marks),
        dirt=tuple(dirt),
        wall_dn=wall,
        opening_centre_mm=(-world.width_mm / 2.0, world.height_mm / 2.0),
        opening_half_mm=(world.width_mm / 2.0, world.height_mm / 2.0),
        corner_radius_mm=world.corner_radius_mm,
    )


def _edge_length(world: World, edge: EdgeSide) -> float:
    return world.width_mm if edge == "top" else world.height_mm
