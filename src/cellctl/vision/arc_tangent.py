"""The arc corner's orientation from its end tangents (issue 21; paper 4.2, "derive the lines from
its centre, radius and tangent directions").

Where a straight edge is in view beyond an end of the arc, its sub-pixel points (from the tangent
point outwards) give a line; it must touch the fitted circle (an occluder's border or a shadow does
not) and be long and straight enough. Its angle then comes from the arc and the edge fitted as one
outline, the circle and its tangent (:func:`fit_arc_and_tangent`): the tangent point pins the line,
which narrows the angle's scatter (0.0017 against 0.0028 deg median on the twin's door window). It
assumes the edge is the arc's tangent: a standoff too small to see (the twin's gaps scatter by 0.02 px)
turns it by 0.13 deg per px, so it counts only where the edge's own line stands within
``tangent.joint_fit_max_gap_px`` of the arc and agrees with it. theta is the top edge's angle to u and the right
edge's to v (their mean when both are seen, which must then agree); without such an edge the
orientation needs a second feature and is None, with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from cellctl.config.arc_vision import ArcCornerConfig
from cellctl.config.vision import FitConfig, VisionConfig
from cellctl.vision.arc import arc_crossings
from cellctl.vision.edge import background_consistent, robust_line_fit
from cellctl.vision.lens import Lens
from cellctl.vision.lines import Line2D, fit_line, ransac_line

F64 = NDArray[np.float64]

# The joint fit's angle must agree with the edge's own line within this many of its sigmas (or the
# floor): otherwise the arc and the edge are not one outline and the edge's own line counts.
_AGREE_SIGMAS = 5.0
_AGREE_FLOOR_RAD = np.radians(0.01)

# Per edge: unit vector from the centre to the tangent point and along the edge away from the arc
# (upright corner, image frame: u right, v down).
_SIDES: dict[str, tuple[F64, F64]] = {
    "top": (np.array([0.0, -1.0]), np.array([-1.0, 0.0])),
    "right": (np.array([1.0, 0.0]), np.array([0.0, 1.0])),
}


@dataclass(frozen=True)
class TangentEdge:
    """A straight edge beyond the arc: its line (ideal px), angle (top to u, right to v; rad) and checks.

    ``line`` and ``angle_rad`` are the tangent of the arc-and-edge fit where it holds (the own line
    within ``tangent.joint_fit_max_gap_px`` of the arc, the two angles agreeing), else the edge's own
    line's; ``free_line`` is the own line fit, on which the checks (straightness, tangency gap, angle
    sigma) are made.
    """

    name: str
    line: Line2D
    angle_rad: float
    sigma_angle_rad: float
    length_px: float
    points: int
    rms_px: float
    gap_px: float  # distance of the circle's centre from the line minus the radius
    reason: str  # why it does not give the orientation ("" when it does)
    points_px: F64 = field(default_factory=lambda: np.zeros((0, 2)))  # the line's inlier points, ideal px
    free_line: Line2D | None = None

    @property
    def ok(self) -> bool:
        return not self.reason


@dataclass(frozen=True)
class ArcOrientation:
    """theta (rad, positive from u towards v) or None with ``reason``; the edges that were tried."""

    theta_rad: float | None
    reason: str
    top: TangentEdge | None
    right: TangentEdge | None


def _rot(theta: float) -> F64:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def fit_arc_and_tangent(
    arc_px: F64, edge_px: F64, centre_px: F64, radius_px: float, towards_edge: F64, theta0_rad: float, iterations: int = 10
) -> tuple[F64, float, float, float]:
    """The circle and its tangent at angle theta fitted as one outline (square px; paper 4.2, "derive the
    lines from its centre, radius and tangent directions").

    Residuals: ``|p - c| - R`` for the arc's points, ``n(theta) . (p - c) - R`` for the edge's, with
    ``n(theta) = rot(theta) towards_edge`` (the unit vector from the centre to the tangent point at
    theta = 0). Gauss-Newton from the separate fits. Returns centre, R, theta (rad) and theta's
    1-sigma from the fit's covariance.
    """
    p = np.array([centre_px[0], centre_px[1], radius_px, theta0_rad], dtype=float)
    e = np.asarray(towards_edge, dtype=float)
    J = np.zeros((len(arc_px) + len(edge_px), 4))
    r = np.zeros(len(J))
    for _ in range(iterations):
        c, R, th = p[:2], p[2], p[3]
        d = arc_px - c
        dist = np.hypot(d[:, 0], d[:, 1])
        n, dn = _rot(th) @ e, _rot(th + 0.5 * np.pi) @ e
        q = edge_px - c
        k = len(arc_px)
        r[:k], r[k:] = dist - R, q @ n - R
        J[:k, :2], J[:k, 2], J[:k, 3] = -d / dist[:, None], -1.0, 0.0
        J[k:, :2], J[k:, 2], J[k:, 3] = -n, -1.0, q @ dn
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        p += step
        if abs(step[3]) < 1e-12 and np.all(np.abs(step[:3]) < 1e-9):
            break
    s2 = float(r @ r) / max(len(r) - 4, 1)
    cov = s2 * np.linalg.pinv(J.T @ J)
    return p[:2].copy(), float(p[2]), float(p[3]), float(np.sqrt(max(cov[3, 3], 0.0)))


def _tangent_line(lens: Lens, name: str, centre_sq: F64, radius: float, theta_sq: float) -> tuple[Line2D, float]:
    """The fitted tangent in ideal px and its angle (top to u, right to v; rad)."""
    e, a = _SIDES[name]
    foot = centre_sq + radius * (_rot(theta_sq) @ e)
    ends = lens.from_square(np.vstack([foot, foot + 100.0 * (_rot(theta_sq) @ a)]))
    d = ends[1] - ends[0]
    line = Line2D(ends[0], d / float(np.hypot(d[0], d[1])))
    return line, _angle(name, line)


def _angle(name: str, line: Line2D) -> float:
    """A line's angle (ideal px; rad): the top edge's to u, the right edge's to v."""
    d = line.oriented([1.0, 0.0] if name == "top" else [0.0, 1.0]).direction
    return float(np.arctan2(d[1], d[0])) if name == "top" else float(np.arctan2(-d[0], d[1]))


@lru_cache(maxsize=8)
def _line_fit_config(band_px: float, iterations: int, robust_k: float, min_band_px: float) -> VisionConfig:
    """The straight edges' robust line fit is the corner detector's (cellctl.vision.edge)."""
    fit = FitConfig(subpixel_band_px=band_px, ransac_iterations=iterations, robust_k=robust_k, min_robust_band_px=min_band_px)
    return VisionConfig(fit=fit)


def _square_angle(lens: Lens, name: str, line: Line2D) -> float:
    """The angle (top to u, right to v; rad) of an ideal-px line in square px."""
    ends = lens.to_square(np.vstack([line.point, line.point + 100.0 * line.direction]))
    d = ends[1] - ends[0]
    return _angle(name, Line2D(ends[0], d / float(np.hypot(d[0], d[1]))))


def _edge(
    img: NDArray[np.uint8], lens: Lens, name: str, pixels: F64, centre: F64, radius: float, arc_sq: F64,
    config: ArcCornerConfig, search_px: float, rng: np.random.Generator,
) -> TangentEdge | str:
    """The straight edge ``name`` beyond the arc (``arc_sq``: the arc's points, square px), or why none is seen."""
    e, a = _SIDES[name]
    tc, s = config.tangent, config.search
    tilt = np.radians(tc.max_tilt_deg)
    q = pixels - centre
    along, across = q @ a, q @ e
    band = s.ransac_band_px * s.downscale
    near = (along > 0) & (np.abs(across - radius) <= along * np.tan(tilt) + radius * (1 - np.cos(tilt)) + band)
    if near.sum() < 10:
        return "no straight edge beyond the arc in view"
    mask = ransac_line(pixels[near], band, s.ransac_iterations, rng)
    if mask.sum() < 10:
        return "no straight edge beyond the arc in view"
    seed = fit_line(pixels[near][mask]).line.oriented(a)
    # From the tangent point (the foot of the centre on the line) outwards, in steps of 0.5 px.
    t0 = float(seed.along(centre[None])[0]) + tc.start_px
    t = t0 + np.arange(0.0, 2.0 * (lens.width_px + lens.height_px), 0.5)
    ideal = seed.at(t)
    roi, m = config.roi, float(s.border_margin_px)
    raw = lens.distort(ideal)
    inside = np.all((raw >= [roi.x_px + m, roi.y_px + m]) & (raw <= [roi.x_px + roi.width_px - 1 - m, roi.y_px + roi.height_px - 1 - m]), axis=1)
    stop = int(np.argmin(inside)) if not np.all(inside) else len(inside)
    if stop < 10:
        return "no straight edge beyond the arc in view"
    outward = seed.normal if float(seed.normal @ e) > 0 else -seed.normal
    found = arc_crossings(
        img, lens, ideal[:stop], np.repeat(outward[None], stop, axis=0), step_px=1,
        expect_dark=config.opening_polarity == "darker", search_px=search_px, level_samples=s.level_samples,
        max_blur_sigma_px=s.max_blur_sigma_px,
    )
    order = np.argsort(found.order, kind="stable")
    usable = found.usable[order] & (found.contrast[order] >= 0.5 * config.limits.min_contrast_dn)
    levels = (found.levels[0][order], found.levels[1][order])
    usable &= background_consistent(levels, usable, s.background_tolerance)
    if usable.sum() < tc.min_points:
        return f"{int(usable.sum())} points on the straight {name} edge (fewer than {tc.min_points})"
    pts = lens.undistort(found.raw_px[order][usable])
    cfg = _line_fit_config(max(s.min_robust_band_px, 0.5), s.ransac_iterations, s.robust_k, s.min_robust_band_px)
    fitted = robust_line_fit(pts, cfg, rng)
    if fitted is None:
        return f"no line fits the straight {name} edge's points"
    fit, inl = fitted
    line = fit.line.oriented(a)
    angle = _angle(name, line)
    span = line.along(pts[inl])
    length = float(span.max() - span.min())
    # The arc is an ellipse in the ideal image (half-axes R and R fy / fx): its support along the line's normal.
    n = line.normal
    gap = abs(float(line.signed_distance(centre[None])[0])) - radius * float(np.hypot(n[0], n[1] * lens.fy / lens.fx))
    reasons = []
    if int(inl.sum()) < tc.min_points or length < tc.min_length_px:
        reasons.append(f"straight run {length:.0f} px with {int(inl.sum())} points (at least {tc.min_length_px:g} px, {tc.min_points})")
    if fit.rms_px > tc.max_rms_px:
        reasons.append(f"line rms {fit.rms_px:.3f} px (at most {tc.max_rms_px:g})")
    if abs(gap) > tc.max_tangent_gap_px:
        reasons.append(f"not tangent to the arc: gap {gap:+.2f} px (at most {tc.max_tangent_gap_px:g})")
    if np.degrees(fit.sigma_angle_rad) > tc.max_angle_sigma_deg:
        reasons.append(f"angle sigma {np.degrees(fit.sigma_angle_rad):.3f} deg (at most {tc.max_angle_sigma_deg:g})")
    why = f"the {name} edge: " + "; ".join(reasons) if reasons else ""
    joint = None
    if not why and abs(gap) <= tc.joint_fit_max_gap_px:
        joint = tangent_of_outline(lens, name, arc_sq, pts[inl], centre, radius, line, fit.sigma_angle_rad)
    tangent, theta, sigma = joint if joint is not None else (line, angle, fit.sigma_angle_rad)
    return TangentEdge(name, tangent, theta, sigma, length, int(inl.sum()), fit.rms_px, gap, why, pts[inl], line)


def tangent_of_outline(
    lens: Lens, name: str, arc_sq: F64, edge_px: F64, centre_px: F64, radius_sq: float, own: Line2D, own_sigma_rad: float
) -> tuple[Line2D, float, float] | None:
    """The edge ``name`` as the tangent of the arc-and-edge fit: its line (ideal px), angle and 1-sigma (rad).

    None where the arc and the edge are not one outline: the tangent's angle more than 5 of the own
    line's sigmas (at least 0.01 deg) from the own line's; the edge's own line counts then. The
    tangency gap check allows 0.5 px, and an edge standing 1 px off the arc turns the joint fit by
    about 0.13 deg on a 1970 px radius.
    """
    e = _SIDES[name][0]
    c_sq, R_sq, theta_sq, sigma = fit_arc_and_tangent(
        arc_sq, lens.to_square(edge_px), lens.to_square(centre_px[None])[0], radius_sq, e, _square_angle(lens, name, own)
    )
    tangent, theta = _tangent_line(lens, name, c_sq, R_sq, theta_sq)
    if not np.isfinite(theta) or abs(theta - _angle(name, own)) > max(_AGREE_SIGMAS * own_sigma_rad, _AGREE_FLOOR_RAD):
        return None
    return tangent, theta, sigma


def measure_orientation(
    img: NDArray[np.uint8], lens: Lens, pixels: F64, centre: F64, radius: float, arc_sq: F64,
    config: ArcCornerConfig, search_px: float, rng: np.random.Generator,
) -> ArcOrientation:
    """theta from the straight edges beyond the arc (``pixels``: Canny pixels, ideal px; ``arc_sq``: the
    arc's fitted points, square px), or None and why."""
    edges: dict[str, TangentEdge | None] = {}
    reasons = []
    for name in ("top", "right"):
        got = _edge(img, lens, name, pixels, centre, radius, arc_sq, config, search_px, rng)
        edges[name] = got if isinstance(got, TangentEdge) else None
        if isinstance(got, str):
            reasons.append(f"the {name} edge: {got}")
        elif not got.ok:
            reasons.append(got.reason)
    good = [e for e in edges.values() if e is not None and e.ok]
    top, right = edges["top"], edges["right"]
    if not good:
        return ArcOrientation(None, "orientation needs a second feature: " + "; ".join(reasons), top, right)
    if len(good) == 2:
        skew = np.degrees(abs(good[0].angle_rad - good[1].angle_rad))
        tol = config.tangent.perpendicular_tolerance_deg
        if skew > tol:
            why = f"the two straight edges are {skew:.2f} deg off a right angle (at most {tol:g})"
            return ArcOrientation(None, why, top, right)
        return ArcOrientation(0.5 * (good[0].angle_rad + good[1].angle_rad), "", top, right)
    return ArcOrientation(good[0].angle_rad, f"from the {good[0].name} edge only", top, right)
