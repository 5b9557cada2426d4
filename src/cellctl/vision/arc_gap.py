"""The post-install inspection on an arc corner (issue 21): the glass's arc inside the opening's.

The glass's outline is the opening's inset by the nominal gap, so at the corner its arc is
concentric with the opening's, of radius R - gap. From one image at the shooting pose:

1. The opening's arc and its top edge: the shot's detector with the recipe's feature rule.
2. The glass's arc: across the opening's arc (cellctl.vision.arc_profile), the strongest step
   within ``search_px`` of the nominal gap inside it; that circle measured alone, with the glass's
   top edge beyond it for the orientation.
3. In mm (:func:`in_plane_from_arcs`): both centres and top edges through the nine-point map, the
   glass's moved along its rays to its depth (parallax, as cellctl.vision.gap_figures). Each glass
   point gets its own depth from the flush's glass plane ``z = dz - dRy x + dRx y``: the arc and
   its top edge run 100-300 mm from the axis, where one depth for a glass tilted 1 deg moves the
   arc's centre by ~0.4 mm and turns the top line by ~0.1 deg. The circle and line are fitted in
   the glass's plane (the tilt's foreshortening undone) and taken back to T's (x, y).
   A frame's corner lies at ``centre - R(phi) (-R, R)`` (the arc's centre at (-R, R) in its own
   frame, the glass's too: it is concentric), so the glass frame's offset from the opening's, in
   the opening's axes, is ``R(-phi_o) (G - O)`` and its turn ``phi_g - phi_o``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cellctl.config.arc_vision import ArcCornerConfig
from cellctl.geometry.planar import rot2, wrap_angle
from cellctl.vision.arc import fit_circle
from cellctl.vision.arc_corner import ArcCornerMeasurement, detect_arc_corner, measure_circle
from cellctl.vision.arc_profile import arc_profile
from cellctl.vision.gap_figures import InPlaneGaps, line_to_mm
from cellctl.vision.lens import Lens
from cellctl.vision.lines import Line2D
from cellctl.vision.ninepoint import AffineMap

F64 = NDArray[np.float64]

__all__ = ["ArcGapMeasurement", "in_plane_from_arcs", "measure_arc_gaps"]

GLASS_SIGMA_FACTOR = 2.5


@dataclass(frozen=True)
class ArcGapMeasurement:
    """The opening's and the glass's arcs (each with its top edge), or the reason there are not both."""

    opening: ArcCornerMeasurement
    glass: ArcCornerMeasurement | None
    message: str

    @property
    def ok(self) -> bool:
        return self.glass is not None and self.glass.ok and _top(self.glass) is not None and _top(self.opening) is not None


def _top(m: ArcCornerMeasurement) -> Line2D | None:
    o = m.orientation
    return o.top.line if o is not None and o.top is not None and o.top.ok else None


def measure_arc_gaps(
    image: NDArray[np.uint8], lens: Lens, config: ArcCornerConfig, *, gap_px_expected: float, search_px: float
) -> ArcGapMeasurement:
    """The opening's arc (the recipe's feature) and the glass's arc about ``gap_px_expected`` inside it."""
    opening = detect_arc_corner(image, lens, config)
    if not opening.ok or opening.centre_px is None or opening.radius_px is None:
        return ArcGapMeasurement(opening, None, f"the opening's arc: {opening.message}")
    if _top(opening) is None:
        return ArcGapMeasurement(opening, None, "the opening's top edge is not in view beyond its arc")
    c = opening.centre_px
    d = opening.points_ideal[opening.inliers] - c
    normals = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    mean = normals.sum(axis=0)
    mid = mean / max(float(np.linalg.norm(mean)), 1e-9)
    darker = config.opening_polarity == "darker"
    profile = arc_profile(image, lens, c, opening.radius_px, normals, opening_darker=darker, feature=config.feature)
    near = [s for s in profile.steps if abs(s.offset_px - gap_px_expected) <= search_px]
    if not near:
        where = ", ".join(f"{s.offset_px:.0f}" for s in profile.steps)
        return ArcGapMeasurement(
            opening, None, f"no step {gap_px_expected:.0f} +- {search_px:.0f} px inside the opening's arc (steps at {where} px): "
            "is the glass in the opening?"
        )  # fmt: skip
    step = max(near, key=lambda s: abs(s.change_dn))
    radius = opening.radius_px - step.offset_px
    # The glass's edge is softer than the wall's (its rms about twice): its fits are held to GLASS_SIGMA_FACTOR x the limits.
    limits = config.limits.model_copy(update={"max_centre_sigma_px": GLASS_SIGMA_FACTOR * config.limits.max_centre_sigma_px,
                                              "max_rms_px": GLASS_SIGMA_FACTOR * config.limits.max_rms_px})
    tangent = config.tangent.model_copy(update={"max_rms_px": GLASS_SIGMA_FACTOR * config.tangent.max_rms_px})
    glass_config = config.model_copy(update={"expected_radius_px": radius, "limits": limits, "tangent": tangent})
    rng = np.random.default_rng(config.search.seed)
    glass = measure_circle(
        lens.check_image(image), lens, glass_config, c, radius, normals, mid, opening.edge_pixels, step.change_dn < 0, rng
    )
    if not glass.ok:
        return ArcGapMeasurement(opening, glass, f"the glass's arc: {glass.message}")
    if _top(glass) is None:
        return ArcGapMeasurement(opening, glass, "the glass's top edge is not in view beyond its arc")
    return ArcGapMeasurement(opening, glass, "both arcs found")


def _on_glass(p: F64, foot: F64, D: float, dz: float, slope: F64) -> F64:
    """Where the rays through wall points ``p`` (mm, T's x, y; camera at depth -D over ``foot``) meet
    the glass plane ``z = dz + slope . (x, y)`` (+ into the wall): their x, y (mm)."""
    s = (D + dz + float(slope @ foot)) / (D - (p - foot) @ slope)
    return foot + (p - foot) * s[:, None]


def _tilt_2x2(drx_rad: float, dry_rad: float) -> F64:
    """The glass plane's (x, y) to T's (x, y) under its tilt (rows and columns 0, 1 of Ry Rx)."""
    return np.array([[math.cos(dry_rad), math.sin(dry_rad) * math.sin(drx_rad)], [0.0, math.cos(drx_rad)]])


def in_plane_from_arcs(
    m: ArcGapMeasurement, nine_point: AffineMap, lens: Lens, *, radius_mm: float, dz_mm: float, drx_rad: float,
    dry_rad: float, working_distance_mm: float,
) -> InPlaneGaps:
    """The glass's in-plane figures against the opening from the two arcs (module docstring).

    ``dz_mm``, ``drx_rad``, ``dry_rad``: the flush's glass plane against the wall in T (+ into the
    wall, cellctl.inspection.flush); T is taken as the opening's measured frame here (the map's
    origin is the taught aim, not T's). ``top_gap_mm`` is the gap between the top edges at the
    opening's top tangent point, ``right_gap_mm`` the gap across the arc at its middle (the right
    edge is out of view there): the radii's difference plus the centres' offset along that radius.
    """
    if not m.ok:
        raise ValueError(f"the arcs were not both measured: {m.message}")
    glass = m.glass
    assert glass is not None and glass.centre_px is not None and m.opening.centre_px is not None
    top = _top(glass)
    assert top is not None
    assert m.opening.radius_px is not None and glass.radius_px is not None
    D, mm_per_px = working_distance_mm, nine_point.mm_per_px
    scale = (D + dz_mm) / D
    o_top = line_to_mm(_top(m.opening), nine_point)  # type: ignore[arg-type]
    phi_o = math.atan2(-o_top.direction[1], -o_top.direction[0])  # the top line points to -x
    arc_centre = np.array([-radius_mm, radius_mm])
    O = nine_point.apply(m.opening.centre_px[None])[0] - rot2(phi_o) @ arc_centre

    def in_T(px: F64) -> F64:
        """Ideal px (N, 2) to mm in the opening's frame (T's x, y)."""
        return (nine_point.apply(px) - O) @ rot2(phi_o)

    foot = in_T(np.array([[lens.cx, lens.cy]]))[0]
    slope, tilt = np.array([-dry_rad, drx_rad]), _tilt_2x2(drx_rad, dry_rad)
    untilt = np.linalg.inv(tilt)
    ends = _on_glass(in_T(np.vstack([top.point, top.point + 100.0 * top.direction])), foot, D, dz_mm, slope) @ untilt.T
    g_top = Line2D(ends[0], (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0]))  # in the glass's plane
    # The glass's circle: the detector's scaled for dz at T's origin, moved by what each point's own depth changes in a fit.
    pts = in_T(glass.points_ideal[glass.inliers])
    c_flat, r_flat = fit_circle(foot + (pts - foot) * scale)
    c_own, r_own = fit_circle(_on_glass(pts, foot, D, dz_mm, slope) @ untilt.T)
    g_c = foot + (in_T(glass.centre_px[None])[0] - foot) * scale + (c_own - c_flat)
    phi_g = math.atan2(-g_top.direction[1], -g_top.direction[0])  # against the opening's
    d = tilt @ (g_c - rot2(phi_g) @ arc_centre)  # G's origin, back in T's (x, y)
    g_c, g_point = tilt @ g_c, tilt @ g_top.point
    n = g_top.normal if g_top.normal[1] >= 0 else -g_top.normal
    mid = np.array([1.0, -1.0]) / math.sqrt(2.0)  # from the arc's centre through its middle, to the corner
    return InPlaneGaps(
        dx_mm=float(d[0]),
        dy_mm=float(d[1]),
        drz_rad=wrap_angle(phi_g),
        top_gap_mm=float((g_point - np.array([-radius_mm, 0.0])) @ n),  # from the opening's top tangent point
        right_gap_mm=float(m.opening.radius_px * mm_per_px - glass.radius_px * mm_per_px * scale - (r_own - r_flat)
                           + (arc_centre - g_c) @ mid),
        top_angle_rad=float(phi_g),
        right_angle_rad=float("nan"),
        reference_along_mm=radius_mm,
        opening_corner_mm=O,
        opening_angle_rad=phi_o,
        glass_corner_mm=O + rot2(phi_o) @ d,
        glass_angle_rad=phi_o + phi_g,
        parallax_scale=scale,
        foot_mm=O + rot2(phi_o) @ foot,
    )
