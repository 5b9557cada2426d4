"""The post-install inspection on an arc corner (issue 21): the glass's arc inside the opening's.

The glass's outline is the opening's inset by the nominal gap, so at the corner its arc is
concentric with the opening's, of radius R - gap. From one image at the shooting pose:

1. The opening's arc and its top edge: the shot's detector with the recipe's feature rule.
2. The glass's arc: across the opening's arc (cellctl.vision.arc_profile), the strongest step
   within ``search_px`` of the nominal gap inside it; that circle measured alone, with the glass's
   top edge beyond it for the orientation.
3. In mm (:func:`in_plane_from_arcs`): both centres and top edges through the nine-point map, the
   glass's scaled about the optical axis' foot for its depth (parallax, as cellctl.vision.gap_figures).
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


def in_plane_from_arcs(
    m: ArcGapMeasurement, nine_point: AffineMap, lens: Lens, *, radius_mm: float, dz_mm: float,
    working_distance_mm: float,
) -> InPlaneGaps:
    """The glass's in-plane figures against the opening from the two arcs (module docstring).

    ``top_gap_mm`` is the gap between the top edges at the opening's top tangent point,
    ``right_gap_mm`` the gap across the arc at its middle (the right edge is out of view there):
    the radii's difference plus the centres' offset along that radius.
    """
    if not m.ok:
        raise ValueError(f"the arcs were not both measured: {m.message}")
    glass = m.glass
    assert glass is not None and glass.centre_px is not None and m.opening.centre_px is not None
    foot = nine_point.apply(np.array([[lens.cx, lens.cy]]))[0]
    scale = (working_distance_mm + dz_mm) / working_distance_mm
    o_top = line_to_mm(_top(m.opening), nine_point)  # type: ignore[arg-type]
    g_top = line_to_mm(_top(glass), nine_point, foot_mm=foot, scale=scale)  # type: ignore[arg-type]
    phi_o = math.atan2(-o_top.direction[1], -o_top.direction[0])  # the top line points to -x
    phi_g = math.atan2(-g_top.direction[1], -g_top.direction[0])
    o_c = nine_point.apply(m.opening.centre_px[None])[0]
    g_c = foot + (nine_point.apply(glass.centre_px[None])[0] - foot) * scale
    arc_centre = np.array([-radius_mm, radius_mm])
    O = o_c - rot2(phi_o) @ arc_centre
    G = g_c - rot2(phi_g) @ arc_centre
    d = rot2(-phi_o) @ (G - O)
    tangent = O + rot2(phi_o) @ np.array([-radius_mm, 0.0])  # the opening's top tangent point
    n = g_top.normal if float(g_top.normal @ (rot2(phi_o) @ np.array([0.0, 1.0]))) >= 0 else -g_top.normal
    mm_per_px = nine_point.mm_per_px
    mid = rot2(phi_o) @ np.array([1.0, -1.0]) / math.sqrt(2.0)  # from the arc's centre through its middle, to the corner
    assert m.opening.radius_px is not None and glass.radius_px is not None
    return InPlaneGaps(
        dx_mm=float(d[0]),
        dy_mm=float(d[1]),
        drz_rad=wrap_angle(phi_g - phi_o),
        top_gap_mm=float((g_top.point - tangent) @ n),
        right_gap_mm=float(m.opening.radius_px * mm_per_px - glass.radius_px * mm_per_px * scale + (o_c - g_c) @ mid),
        top_angle_rad=float(phi_g - phi_o),
        right_angle_rad=float("nan"),
        reference_along_mm=radius_mm,
        opening_corner_mm=O,
        opening_angle_rad=phi_o,
        glass_corner_mm=G,
        glass_angle_rad=phi_g,
        parallax_scale=scale,
        foot_mm=foot,
    )
