"""Which feature a recipe's shot measures, where the camera aims, and where the feature lies in T.

The corner method (paper 4.2) needs a straight stretch of both edges beside the corner's arc in
view; where the recipe's corner radius leaves less than ``MIN_STRAIGHT_EDGE_MM`` of it, the arc is
the feature (issue 21): its centre (u, v), the orientation from the top edge's straight run beyond
it. At the shooting pose the camera's axes lie along T's (x along the image's u, y along v), its
optical axis through the aim point ``vision.shot_aim_mm``. The corner method's edge points start past
the arc (:meth:`CornerRadius.exclusion_px`); where that leaves too short a straight run with the corner
at the image's centre (radii over about 31 mm), the default aim moves the corner towards the image's
upper right (:func:`corner_shift_px`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np

from cellctl.config.arc_vision import ArcCornerConfig
from cellctl.config.vision import FitConfig, LimitsConfig

if TYPE_CHECKING:
    from cellctl.config.schema import CellConfig

MIN_STRAIGHT_EDGE_MM = 20.0  # of each edge beside the arc, for the corner method
# The arc's default aim: the top edge's tangent point at these shares of the image's width and
# height, so the arc runs from it down to the right and the straight top edge runs on to the left.
_ARC_TANGENT_AT = (0.22, 0.15)
_PLACEMENT_MARGIN_DEG = 8.0  # coverage kept beyond the limit for the car body's placement error
# The corner method's straight run of each edge in view, per px of its exclusion (the arc and the margin left out): the
# paper's cell with its 30 mm corner at the image's centre has 572 px beyond 440 px. The corner's sigma is the lines'
# extrapolated from their runs' middles, so it holds where the run grows with the exclusion (the twin's 45 and 55 mm
# corners at the centre: 23 and 39 of 40 shots refused for it; moved so: none of 100, p99 0.07 and 0.11 px).
_STRAIGHT_PER_EXCLUSION = 1.3
# How far from its nominal pixel (layout.camera's principal point) the shooting pose may put the corner: the
# real lens's principal point and the hand-eye's error (the twin's lens: 9 px and 12 px off the data sheet's).
_CORNER_MARGIN_PX = 40.0
# How far past the corner's arc (its tangent points, the radius from the virtual corner) [vision.gap]'s window must
# start: the window is set in nominal px, and the real scale may differ from layout.camera's by the nine-point map's
# 3 % (calibration.pixel_map.MAP_SCALE_TOLERANCE), 1 mm at the window's ~34 mm. The twin's inspection holds 0.01 mm
# with the window up to 4 mm onto the arc, and is 0.03 mm off at 11 mm (a 45 mm radius), refused as bowed at 16 mm.
GAP_PAST_ARC_MM = 1.0

FeatureKind = Literal["corner", "arc"]


def feature_kind(config: CellConfig) -> FeatureKind:
    """"arc" when the corner radius leaves less straight edge in view than the corner method needs."""
    fov_w, fov_h = config.layout.camera.field_of_view_mm(config.process.working_distance_mm)
    straight = min(fov_w, fov_h) / 2.0 - config.layout.opening.corner_radius_mm
    return "arc" if straight < MIN_STRAIGHT_EDGE_MM else "corner"


def feature_point_mm(config: CellConfig) -> tuple[float, float]:
    """Where the measured feature lies in T (x, y; mm): the virtual corner, or the arc's centre."""
    if feature_kind(config) == "corner":
        return (0.0, 0.0)
    r = float(config.layout.opening.corner_radius_mm)
    return (-r, r)


def _mm_per_px(config: CellConfig) -> tuple[float, float]:
    cam, d = config.layout.camera, config.process.working_distance_mm
    return d / cam.fx, d / cam.fy


def shot_aim_mm(config: CellConfig) -> tuple[float, float]:
    """The T point (x, y; mm) on the camera's axis at the shooting pose."""
    if config.vision.shot_aim_mm is not None:
        return (float(config.vision.shot_aim_mm[0]), float(config.vision.shot_aim_mm[1]))
    sx, sy = _mm_per_px(config)
    if feature_kind(config) == "corner":
        d = corner_shift_px(config)
        return (-d * sx, d * sy) if d > 0 else (0.0, 0.0)
    cam, r = config.layout.camera, float(config.layout.opening.corner_radius_mm)
    u, v = _ARC_TANGENT_AT[0] * cam.width_px, _ARC_TANGENT_AT[1] * cam.height_px
    return (-r - (u - cam.cx) * sx, -(v - cam.cy) * sy)


def corner_shift_px(config: CellConfig) -> float:
    """How far (px, whole) the corner method's default aim puts the virtual corner right of and above the image centre.

    0 while each edge's straight run in view beyond the arc's exclusion is ``_STRAIGHT_PER_EXCLUSION`` times the
    exclusion with the corner at the centre; else as far as that needs, but keeping the wall beside each edge in view
    for the feature's profile (``vision.feature.profile_half_px``, the border margin and ``_CORNER_MARGIN_PX``).
    """
    cam, v = config.layout.camera, config.vision
    exclusion = corner_radius(config).exclusion_px(v.fit, v.limits)
    margin = float(v.fit.border_margin_px)
    room = min(cam.cx, cam.height_px - cam.cy)  # px from the centre to the border along each edge's run, left and down
    need = (1.0 + _STRAIGHT_PER_EXCLUSION) * exclusion + margin - room
    wall = min(cam.cy, cam.width_px - cam.cx) - v.feature.profile_half_px - margin - _CORNER_MARGIN_PX
    return float(max(0, round(min(need, wall))))


def _to_px(config: CellConfig, xy: np.ndarray) -> np.ndarray:
    """T points (N, 2) to pixels of the nominal shooting image (square to the wall, no distortion)."""
    cam = config.layout.camera
    ax, ay = shot_aim_mm(config)
    sx, sy = _mm_per_px(config)
    return np.column_stack([cam.cx + (xy[:, 0] - ax) / sx, cam.cy + (xy[:, 1] - ay) / sy])


def arc_view(config: CellConfig) -> tuple[float, float]:
    """At the nominal shooting pose: the arc's angle in the ROI (deg) and the top edge's straight run (px).

    Without the lens's distortion: the barrel pulls the image's borders in, so the raw image shows a
    little more than this counts.
    """
    r = float(config.layout.opening.corner_radius_mm)
    roi, margin = config.vision.roi, float(config.vision.arc.search.border_margin_px)
    lo = np.array([roi.x_px + margin, roi.y_px + margin])
    hi = np.array([roi.x_px + roi.width_px - 1 - margin, roi.y_px + roi.height_px - 1 - margin])
    phi = np.radians(np.arange(0.0, 90.0 + 1e-9, 0.25))
    arc = np.column_stack([-r + r * np.cos(phi), r - r * np.sin(phi)])
    arc_px = _to_px(config, arc)
    seen = np.all((arc_px >= lo) & (arc_px <= hi), axis=1)
    coverage = 0.25 * float(np.sum(seen))
    run = np.column_stack([-r - np.arange(0.0, 400.0, 0.5), np.zeros(800)])
    run_px = _to_px(config, run)
    inside = np.all((run_px >= lo) & (run_px <= hi), axis=1)
    straight = float(np.hypot(*(run_px[inside][-1] - run_px[inside][0]))) if inside.sum() > 1 else 0.0
    return coverage, straight


def arc_view_problem(config: CellConfig) -> str | None:
    """Why the arc cannot be measured at the shooting pose (the aim, the polarity), or None."""
    if config.vision.opening_polarity == "auto":
        return "vision.opening_polarity = auto: the arc corner needs darker or brighter (the side its centre lies on)"
    coverage, straight = arc_view(config)
    lim, tan = config.vision.arc.limits, config.vision.arc.tangent
    need = lim.min_coverage_deg + _PLACEMENT_MARGIN_DEG
    if coverage < need or straight < 2.0 * tan.min_length_px:
        r = config.layout.opening.corner_radius_mm
        return (
            f"vision.shot_aim_mm = {tuple(round(v, 1) for v in shot_aim_mm(config))}: the {r:g} mm corner's arc spans "
            f"{coverage:.0f} deg of the view (at least {need:g}) and the top edge runs {straight:.0f} px beyond it "
            f"(at least {2.0 * tan.min_length_px:g}); leave shot_aim_mm out for the default aim or move it"
        )
    return None


def gap_window_problem(config: CellConfig) -> str | None:
    """Why ``[vision.gap]``'s window along the top or the right edge may keep fewer pixels inside the image than the
    inspection measures on (corner method), or None.

    At the nominal shooting pose, as :func:`arc_view` (no distortion). The glass's window, measured from the glass's
    corner ``process.inspect.nominal_gap_mm`` inside the opening's, reaches nearer the border than the opening's;
    the corner is taken ``_CORNER_MARGIN_PX`` nearer it too (the real lens's principal point is not the data sheet's).
    The window must also start ``GAP_PAST_ARC_MM`` past the corner's arc (``layout.opening.corner_radius_mm`` from
    the corner): on the arc, the edges it fits are bent.
    """
    if feature_kind(config) != "corner":
        return None  # the arc corner is inspected on its arcs (cellctl.vision.arc_gap): no window
    g, cam = config.vision.gap, config.layout.camera
    need, need_name = max((g.min_points, "min_points"), (g.cross_sections, "cross_sections"))
    nominal = _to_px(config, np.array([feature_point_mm(config)]))[0]
    gap_mm = float(config.process.inspect.nominal_gap_mm)
    gap_px = gap_mm / _mm_per_px(config)[0]
    t = np.arange(g.start_px, g.start_px + g.length_px + 1e-9, 1.0)
    m = float(g.border_margin_px)
    lo, hi = np.array([m, m]), np.array([cam.width_px - 1 - m, cam.height_px - 1 - m])
    edges = (("top", np.array([-1.0, 0.0]), "left of"), ("right", np.array([0.0, 1.0]), "below"))
    worst = {name: nominal + (_CORNER_MARGIN_PX + gap_px) * away for name, away, _ in edges}  # the glass's corner
    room = min(worst["top"][0] - m, hi[1] - worst["right"][1])  # px from it to the border, along the shorter edge
    r_mm = float(config.layout.opening.corner_radius_mm)
    first = (r_mm + GAP_PAST_ARC_MM) / _mm_per_px(config)[0]  # the first start past the arc
    for name, away, side in edges:
        pts = worst[name] + t[:, None] * away
        inside = int(np.sum(np.all((pts >= lo) & (pts <= hi), axis=1)))
        if inside >= need:
            continue
        needs = f"fewer than the vision.gap.{need_name} = {need} px the inspection measures each edge on"
        if len(t) < need:
            return (f"vision.gap.length_px = {g.length_px:g} gives each edge's window {len(t)} px, {needs}; "
                    f"raise length_px to at least {need - 1}")
        seen = bool(np.all((nominal >= lo + _CORNER_MARGIN_PX) & (nominal <= hi - _CORNER_MARGIN_PX)))
        if not seen:
            fix = "move vision.shot_aim_mm (leave it out: the corner at the image's centre) so the edge runs in view"
        elif room - need + 1 >= first:
            fix = f"lower vision.gap.start_px to at most {room - need + 1:.0f} (keeping it past the corner's arc, {first:.0f} px)"
        else:
            fix = (f"this image leaves {max(room - first + 1, 0.0):.0f} px beyond the corner's arc ({first:.0f} px): "
                   f"set start_px just past the arc and lower vision.gap.{need_name} to fit, or check layout.camera")
        return (
            f"vision.gap.start_px = {g.start_px:g} and length_px = {g.length_px:g} put the {name} edge's window "
            f"{g.start_px:g} to {g.start_px + g.length_px:g} px {side} the corner: the shooting pose puts the opening's "
            f"corner at ({nominal[0]:.0f}, {nominal[1]:.0f}) px by layout.camera (the real lens's within "
            f"{_CORNER_MARGIN_PX:g} px of it) and the glass's process.inspect.nominal_gap_mm = {gap_mm:g} ({gap_px:.0f} px) "
            f"further in, so as little as {inside} px of the glass's window lies inside the {cam.width_px} x "
            f"{cam.height_px} px image (vision.gap.border_margin_px = {g.border_margin_px} from its border), {needs}, "
            f"and the inspection could refuse every cycle; {fix}"
        )
    if g.start_px < first:
        return _on_the_arc(config, r_mm, first, room - need + 1, need, need_name)
    return None


def _on_the_arc(config: CellConfig, r_mm: float, first: float, last: float, need: int, need_name: str) -> str:
    """The refusal of a ``[vision.gap]`` window starting on the corner's arc: ``first`` is the first start past it,
    ``last`` the last that keeps ``need`` px of the window in the image (px along the edge from the corner)."""
    g, mm_per_px = config.vision.gap, _mm_per_px(config)[0]
    tol = config.process.tolerance
    # A glass within tolerance (turned by orientation_deg, off by position_mm) shows its edge this far from the nominal
    # gap at the window's middle, where the median profile finds it: the glass's search must reach it.
    search = (first + g.length_px / 2.0) * math.tan(math.radians(tol.orientation_deg)) + tol.position_mm / mm_per_px
    fix = f"raise vision.gap.start_px (a recipe's in its [process.recipes.vision.gap]) to at least {math.ceil(first)}"
    if search > g.glass_search_px:
        fix += (f" and vision.gap.glass_search_px to at least {math.ceil(search) + 1} (a glass within process.tolerance "
                f"shows its edge up to {search:.0f} px from the nominal gap in the window moved out)")
    kept = need - max(first - last, 0.0)  # px of the window the image holds from that start
    if kept >= need:
        fix += f"; a start up to {last:.0f} px keeps the window in the image"
    elif kept >= 10:
        fix += f", and lower vision.gap.{need_name} to the {kept:.0f} px the image then holds of the window"
    else:
        fix += "; but this image leaves no straight edge past the arc for the window: check layout.camera"
    return (
        f"vision.gap.start_px = {g.start_px:g} ({g.start_px * mm_per_px:.1f} mm at layout.camera's {mm_per_px:.4g} "
        f"mm/px) starts the inspection's window along each edge on the corner's arc: layout.opening.corner_radius_mm = "
        f"{r_mm:g} (a recipe's in its [process.recipes.opening]) ends the arc {r_mm:g} mm from the corner, and the window "
        f"must start at least {GAP_PAST_ARC_MM:g} mm past it or the arc bends the edges the gaps are fitted to (the "
        f"glass's offset off, or every inspection refused as bowed); {fix}"
    )


def arc_corner_config(config: CellConfig) -> ArcCornerConfig:
    """The arc detector's input for this recipe: its radius in square px, ROI, polarity, feature rule, [vision.arc]."""
    v = config.vision
    polarity = "brighter" if v.opening_polarity == "brighter" else "darker"
    radius_px = config.layout.opening.corner_radius_mm * config.layout.camera.fx / config.process.working_distance_mm
    return ArcCornerConfig(
        expected_radius_px=radius_px, roi=v.roi, opening_polarity=polarity, search=v.arc.search,
        limits=v.arc.limits, tangent=v.arc.tangent, feature=v.feature,
    )  # fmt: skip


@dataclass(frozen=True)
class CornerRadius:
    """The opening's corner radius the corner detector's arc check expects (square px), and where it comes from."""

    radius_px: float
    source: str  # for the refusal: the setting and the scale it was converted with

    def exclusion_px(self, fit: FitConfig, limits: LimitsConfig) -> float:
        """From the virtual corner along each edge, where the corner method's edge points start (px).

        ``fit.arc_exclusion_px``, or further where the arc ends beyond it: past an arc up to the radius check's
        ``limits.arc_radius_tolerance`` larger than this radius (its points bend the straight edge's fit).
        """
        return max(float(fit.arc_exclusion_px), (1.0 + float(limits.arc_radius_tolerance)) * self.radius_px)


def corner_radius(config: CellConfig) -> CornerRadius:
    """The recipe's ``layout.opening.corner_radius_mm`` in px at the nominal scale (working distance over fx)."""
    r_mm = float(config.layout.opening.corner_radius_mm)
    mm_per_px = _mm_per_px(config)[0]
    return CornerRadius(r_mm / mm_per_px, f"layout.opening.corner_radius_mm {r_mm:g} mm at {mm_per_px:.4g} mm/px")


@dataclass(frozen=True)
class ShotFeature:
    """What a recipe's shots measure: the arc detector's input (None: the corner method), where
    the feature lies in T (x, y; mm) and, for the corner method, the radius its arc check expects."""

    arc: ArcCornerConfig | None = None
    point_mm: tuple[float, float] = (0.0, 0.0)
    # Derived from the layout, not a choice of detector: left out of ==, which compares the feature.
    corner_radius: CornerRadius | None = field(default=None, compare=False)


def shot_feature(config: CellConfig) -> ShotFeature:
    """The recipe's shot feature (``config`` is a recipe's view, ``config.for_recipe(name)``)."""
    if feature_kind(config) == "corner":
        return ShotFeature(corner_radius=corner_radius(config))
    return ShotFeature(arc_corner_config(config), feature_point_mm(config))
