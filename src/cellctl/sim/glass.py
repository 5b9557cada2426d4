"""The installed glass as the twin's camera and laser see it: its outer surface, its edge and its frit.

When the gripper releases the glass (cellctl.sim.cell), the glass stays at its true pose T_B_G
in the car body. :class:`InstalledGlass` is that glass as a scene object:

- geometry: its outer surface is the plane z = 0 of G. Its outline is the opening's rounded
  rectangle at G inset by the edge gap (centre (-W/2, H/2), half sizes W/2 - gap and H/2 - gap,
  corner radius r - gap), so a perfect install (G on T) leaves the same gap all round;
- looks: the dark ceramic frit band along the edge, ``frit_width_mm`` wide (its inner border the
  level set ``sd = -frit_width`` of the outline's signed distance ``sd``), then the clear glass
  through which the car interior shows; in the gap between the glass's and the opening's edges the
  camera sees the flange the glass is bonded to (or ``gap_dn``);
- the laser: a beam meets the outer surface where it lies inside the outline (front reflection).

Shading (cellctl.sim.camera): a pixel's ray meets the glass's plane and the wall's plane
separately, so a recessed or tilted glass shows its true parallax. The glass covers the wall as a
mark does in cellctl.sim.surface: ``shade += (glass - shade) * coverage(sd)``, the coverage exact
for a straight edge under the renderer's blur and pixel footprint (cellctl.sim.edge_coverage), and
the frit's inner border is a step within the glass the same way. Only the outer surface is drawn:
the edge's ground side face (seen at most ``thickness_mm * tan(field angle)`` wide, under 0.6 mm at
the image border at 400 mm, and none near the optical axis), the frit's halftone dots and a glint
on the edge's arris are not.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.config.sim import GlassConfig
from cellctl.geometry.pose import Pose, apply_pose, check_pose, invert_pose
from cellctl.sim.edge_coverage import coverage_from_sdf, rounded_rect_sdf
from cellctl.sim.surface import DrawnSurface, Jacobian, JacobianAt, Sdf
from cellctl.sim.world import World

F64 = NDArray[np.float64]
Bool = NDArray[np.bool_]

_GREYS_STREAM = zlib.crc32(b"glass.greys")
"""Mixed with the car body's surface seed: the glass's greys are drawn per car body, apart from its surface."""


@dataclass(frozen=True)
class GlassBlockPlan:
    """How the glass classifies the image blocks (see :meth:`InstalledGlass.plan_blocks`).

    Attributes:
        covered: blocks wholly on the glass (no wall shows).
        level: the glass's level of a covered block (frit or clear).
        frit_edge: covered blocks the frit's inner border may cross (shaded per pixel).
        touch: blocks the glass may cover in part or whole (its edge near, or their footprint unknown).
    """

    covered: Bool
    level: F64
    frit_edge: Bool
    touch: Bool


@dataclass(frozen=True, eq=False)
class InstalledGlass:
    """One glass standing in the car body.

    Attributes:
        T_B_G: its true corner frame (outer surface z = 0, z into the wall).
        centre_mm, half_mm, radius_mm: its outline, a rounded rectangle in G's x-y plane.
        edge_gap_mm: the nominal gap its outline keeps from the opening's edge (its edges lie at
            x_G = -gap and y_G = +gap).
        frit_width_mm: the frit band's width from the edge inwards.
        thickness_mm: the glass's thickness (its inner surface lies at z_G = thickness).
        frit_dn, clear_dn: the frit's and the clear glass's greys (DN, as drawn: contrast applied).
        gap_dn: the grey seen in the gap, or None (the drawn surface's first band inside the edge).
        laser_noise_mm, laser_dropout_probability: the laser on the glass (front reflection).
    """

    T_B_G: Pose
    centre_mm: tuple[float, float]
    half_mm: tuple[float, float]
    radius_mm: float
    edge_gap_mm: float
    frit_width_mm: float
    thickness_mm: float
    frit_dn: float
    clear_dn: float
    gap_dn: float | None = None
    laser_noise_mm: float = 0.0
    laser_dropout_probability: float = 0.0

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, InstalledGlass):
            return NotImplemented
        return bool(np.array_equal(self.T_B_G, other.T_B_G)) and all(
            getattr(self, f) == getattr(other, f) for f in self.__dataclass_fields__ if f != "T_B_G"
        )

    __hash__ = None  # type: ignore[assignment]

    # -- geometry --------------------------------------------------------------------------------

    def outline_sdf(self, x: F64, y: F64) -> Sdf:
        """Signed distance (mm, negative on the glass) to the outline at G points (x, y), and its gradient."""
        return rounded_rect_sdf(x, y, self.centre_mm, self.half_mm, self.radius_mm)

    def distance(self, x: F64, y: F64) -> F64:
        """The outline's signed distance alone (the same values as :meth:`outline_sdf`'s)."""
        (cx, cy), (hx, hy), r = self.centre_mm, self.half_mm, self.radius_mm
        qx = np.abs(np.asarray(x, dtype=float) - cx) - (hx - r)
        qy = np.abs(np.asarray(y, dtype=float) - cy) - (hy - r)
        corner = (qx > 0.0) & (qy > 0.0)
        qn = np.sqrt(np.maximum(qx, 0.0) ** 2 + np.maximum(qy, 0.0) ** 2)
        return np.where(corner, qn, np.maximum(qx, qy)) - r

    def ray_hit(self, origin_B: ArrayLike, direction_B: ArrayLike) -> float | None:
        """Distance along a ray to the glass's outer surface where it lies inside the outline, or None.

        The ray must meet the surface from outside the car body (moving along +z of G).
        """
        G_inv = invert_pose(self.T_B_G)
        o = apply_pose(G_inv, np.asarray(origin_B, dtype=float))
        d = G_inv[:3, :3] @ np.asarray(direction_B, dtype=float)
        if d[2] <= 1e-12 or o[2] >= 0.0:
            return None
        t = -o[2] / d[2]
        hit = o + t * d
        if float(self.distance(hit[0], hit[1])) >= 0.0:
            return None
        return float(t)

    def depth_in(self, T_B_T: ArrayLike, xy_T: ArrayLike) -> F64:
        """z in T (mm, + into the wall) of the outer surface above T points (x, y): the true flush there."""
        T = check_pose(T_B_T, "T_B_T")
        E = invert_pose(T) @ self.T_B_G  # G in T
        n = E[:3, 2]  # the glass plane's normal in T
        p = np.atleast_2d(np.asarray(xy_T, dtype=float))
        if abs(n[2]) < 1e-9:
            raise ValueError("the glass stands edge-on to the wall: no flush")
        # Points (x, y, z) on the plane: n . ((x, y, z) - E_t) = 0.
        rest = n[0] * (p[:, 0] - E[0, 3]) + n[1] * (p[:, 1] - E[1, 3])
        return E[2, 3] - rest / n[2]

    # -- looks -----------------------------------------------------------------------------------

    def with_contrast(self, factor: float, mean_dn: float) -> InstalledGlass:
        """The greys scaled by ``factor`` about ``mean_dn`` (as the surface's, cellctl.sim.surface)."""
        if factor == 1.0:
            return self
        scale = lambda v: mean_dn + factor * (v - mean_dn)  # noqa: E731
        return replace(
            self,
            frit_dn=scale(self.frit_dn),
            clear_dn=scale(self.clear_dn),
            gap_dn=None if self.gap_dn is None else scale(self.gap_dn),
        )

    def glaze(self, surface: DrawnSurface) -> DrawnSurface:
        """The car body's surface as it shows around this glass: inside the opening's edge the gap's bottom.

        The steps outside the edge (the paint band) stay; inside it one level remains, ``gap_dn`` or
        the first band's (the flange the glass is bonded to, running on under the glass).
        """
        outside = tuple(s for s in surface.steps if s[0] > 0.0)
        inner = [s for s in surface.steps if s[0] <= 0.0]
        level = inner[0][1] if self.gap_dn is None else self.gap_dn
        return replace(surface, steps=(*outside, (inner[0][0], level)))

    def plan_blocks(self, gx: F64, gy: F64, margin: F64, valid: Bool) -> GlassBlockPlan:
        """Classify blocks by their centre (gx, gy) on the glass's plane and their ``margin`` (mm)."""
        d = self.distance(gx, gy)
        inner = d + self.frit_width_mm
        covered = valid & (d < -margin)
        return GlassBlockPlan(
            covered=covered,
            level=np.where(inner < 0.0, self.clear_dn, self.frit_dn),
            frit_edge=covered & (np.abs(inner) <= margin),
            touch=~valid | (d <= margin),
        )

    def composite(self, shade: F64, X: F64, Y: F64, jac_at: JacobianAt, ok: Bool, sigma_px: float, reach_mm: F64) -> None:
        """Lay the glass over ``shade`` (in place) at its plane's pixel hits (X, Y) with Jacobian ``jac_at``.

        ``ok`` marks pixels whose ray meets the plane; ``reach_mm`` (broadcast to ``X``) bounds the
        blur kernel's reach on the plane: the edge's and the frit border's coverage are computed
        within it and are 0 or 1 beyond (inf: everywhere).
        """
        xf, yf = X.ravel(), Y.ravel()
        reach = np.broadcast_to(reach_mm, X.shape).ravel()
        d = self.distance(xf, yf)
        cover = (d < 0.0).astype(np.float64)
        inner = (d + self.frit_width_mm < 0.0).astype(np.float64)
        close = np.flatnonzero((np.abs(d) <= reach) | (np.abs(d + self.frit_width_mm) <= reach))
        if close.size:
            sd, gx, gy = self.outline_sdf(xf[close], yf[close])
            J = jac_at(close)
            k = np.flatnonzero(np.abs(sd) <= reach[close])
            cover[close[k]] = coverage_from_sdf(sd[k], gx[k], gy[k], _take(J, k), sigma_px)
            sd_in = sd + self.frit_width_mm
            k = np.flatnonzero(np.abs(sd_in) <= reach[close])
            inner[close[k]] = coverage_from_sdf(sd_in[k], gx[k], gy[k], _take(J, k), sigma_px)
        cover *= ok.ravel()
        on = np.flatnonzero(cover > 0.0)
        if on.size == 0:
            return
        flat = shade.reshape(-1)  # a view: shade is contiguous
        value = self.frit_dn + (self.clear_dn - self.frit_dn) * inner[on]
        part = flat[on]
        part += (value - part) * cover[on]
        flat[on] = part


def _take(jac: Jacobian, idx: NDArray[np.intp]) -> Jacobian:
    return (jac[0][idx], jac[1][idx], jac[2][idx], jac[3][idx])


def _draw(rng: np.random.Generator, low_high: tuple[float, float]) -> float:
    """A uniform draw in [low, high] (exactly low when they are equal); always one draw."""
    return float(low_high[0]) + (float(low_high[1]) - float(low_high[0])) * float(rng.random())


def glass_scene(config: GlassConfig, world: World, T_B_G: ArrayLike) -> InstalledGlass:
    """The glass of ``config`` standing at ``T_B_G`` in the car body ``world`` (its greys drawn per car body).

    The outline is the opening's rounded rectangle inset by ``config.edge_gap_mm``; its corner radius
    is the opening's (``world.corner_radius_mm``) minus the gap.
    """
    G = check_pose(T_B_G, "T_B_G")
    gap = float(config.edge_gap_mm)
    radius = float(world.corner_radius_mm) - gap
    if radius < 0.0:
        raise ValueError(
            f"sim.glass.edge_gap_mm ({gap:g}) exceeds the opening's corner radius ({world.corner_radius_mm:g} mm)"
        )
    rng = np.random.default_rng([int(world.surface_seed), _GREYS_STREAM])
    frit = _draw(rng, config.frit_dn)
    clear = _draw(rng, config.clear_dn)
    gap_draw = _draw(rng, config.gap_dn if config.gap_dn is not None else (0.0, 0.0))
    return InstalledGlass(
        T_B_G=G,
        centre_mm=(-config.width_mm / 2.0, config.height_mm / 2.0),
        half_mm=(config.width_mm / 2.0 - gap, config.height_mm / 2.0 - gap),
        radius_mm=radius,
        edge_gap_mm=gap,
        frit_width_mm=float(config.frit_width_mm),
        thickness_mm=float(config.thickness_mm),
        frit_dn=frit,
        clear_dn=clear,
        gap_dn=gap_draw if config.gap_dn is not None else None,
        laser_noise_mm=float(config.laser_noise_mm),
        laser_dropout_probability=float(config.laser_dropout_probability),
    )
