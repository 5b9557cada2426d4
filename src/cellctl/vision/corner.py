"""The window corner: two straight edges, their intersection (u, v) and angle theta (paper 4.2).

Pipeline, for one raw image:

1. Coarse (cellctl.vision.coarse): Canny and probabilistic Hough on the shrunk region of interest
   find the top and right edges beside the rounded upper-right corner, within a few pixels.
2. Seed lines: the Canny pixels near each coarse line are undistorted (the calibrated lens) and a
   RANSAC line through them gives each edge and a provisional corner in the ideal image.
   The feature edge (cellctl.vision.profile): the median profile across each seed line shows
   every edge parallel to it (paint edge, wall edge, flange, seal); the recipe's rule picks the
   feature among them by polarity and place, and the seed line moves onto it.
3. Sub-pixel points: each seed line is sampled from ``arc_exclusion_px`` beyond the corner (the arc
   is left out; given the recipe's radius, from past its arc where that ends further:
   cellctl.config.feature.CornerRadius.exclusion_px) to the edge of the ROI, mapped into the raw
   image, and on every pixel column (top edge) or row (right edge) the edge crossing is measured
   to sub-pixel precision (cellctl.vision.subpixel). Profiles that are saturated, too faint, of the wrong polarity or
   on a disturbed background (a glare veil: see ``background_consistent``) are left out; the
   rest are undistorted.
4. Fit: RANSAC on the sub-pixel points, then least squares on the inliers within a robust band
   (twice). The seed corner is within a few pixels, far less than the margin of the arc
   exclusion, so the points need not be taken again around the refined corner.
5. The corner is the lines' intersection in the ideal image (``corner_px``; also given in the raw
   image, ``corner_raw_px``); theta is the corner's rotation, the mean of the top edge's angle to
   the u axis and the right edge's angle to the v axis (both 0 for an upright corner, positive
   when the image turns from u towards v).
6. Arc check (cellctl.vision.arc): the rounded corner is measured too and both lines must touch
   the circle through it; a line that is the border of an occluder or a shadow does not.

Every figure is checked against :class:`cellctl.config.vision.LimitsConfig`; the first failing
check makes the answer a refusal (a value with the reason), not an exception.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from cellctl.config.feature import CornerRadius
from cellctl.config.vision import FeatureConfig, LimitsConfig, RoiConfig, VisionConfig
from cellctl.vision.arc import ArcMeasurement, estimate_radius, measure_arc
from cellctl.vision.coarse import CoarseFailure, find_coarse_corner
from cellctl.vision.lens import Lens
from cellctl.vision.edge import (
    AWAY, MIN_SEED_POINTS, EdgeMeasurement, EdgeName, SettingNames, measure_edge, too_near_border,
)
from cellctl.vision.lines import Line2D, fit_line, intersect, ransac_line
from cellctl.vision.profile import EdgeProfile, edge_profile, into_opening, pick_feature
from cellctl.vision.quality import Check, Refusal, Refused, at_least, at_most
from cellctl.vision.taught_profile import TaughtProfile, match_taught, rule_problem

F64 = NDArray[np.float64]

__all__ = ["CornerFeatures", "CornerMeasurement", "EdgeMeasurement", "detect_corner"]


@dataclass(frozen=True)
class CornerFeatures:
    """The feature parameters of eq. 16: corner (u, v) in the ideal image and its angle theta."""

    u_px: float
    v_px: float
    theta_rad: float
    top_angle_rad: float
    right_angle_rad: float


@dataclass(frozen=True)
class CornerMeasurement:
    """The detector's answer: a corner with its quality figures, or a refusal with its reason.

    ``corner_px`` is in the ideal image (camera matrix A, no distortion), ``corner_raw_px`` in the
    raw image. ``checks`` lists every quality figure against its limit; ``refusal`` is the reason
    of the first one that failed (None when the corner is accepted) and ``message`` says it in
    words. Partial results (edges found before the refusal) are kept for the annotated image.
    """

    refusal: Refusal | None
    message: str
    roi: RoiConfig
    arc_exclusion_px: float
    corner_px: F64 | None = None
    corner_raw_px: F64 | None = None
    theta_rad: float | None = None
    corner_angle_rad: float | None = None
    corner_sigma_px: float | None = None
    top: EdgeMeasurement | None = None
    right: EdgeMeasurement | None = None
    arc: ArcMeasurement | None = None
    checks: tuple[Check, ...] = ()
    segments: F64 = field(default_factory=lambda: np.zeros((0, 4)))
    coarse_corner_px: F64 | None = None
    """Where the coarse stage put the corner (ideal image), kept on refusals after it: enough to
    re-aim the camera when the corner lies too near the image border to be measured well."""

    @property
    def ok(self) -> bool:
        return self.refusal is None

    @property
    def features(self) -> CornerFeatures:
        """(u, v, theta) for eq. 16; raises ValueError when the detector refused."""
        if self.refusal is not None or self.corner_px is None or self.top is None or self.right is None:
            raise ValueError(f"no corner features: the detector refused ({self.message})")
        return CornerFeatures(
            float(self.corner_px[0]),
            float(self.corner_px[1]),
            float(self.theta_rad),  # type: ignore[arg-type]
            self.top.angle_rad,
            self.right.angle_rad,
        )


def _check_arc(
    img: NDArray[np.uint8],
    lens: Lens,
    corner: F64,
    top: EdgeMeasurement,
    right: EdgeMeasurement,
    pixels: F64,
    dark: bool,
    config: VisionConfig,
    search_px: float,
) -> ArcMeasurement | None:
    """The corner arc measured around the radius the coarse edge pixels suggest (see cellctl.vision.arc)."""
    ideal = lens.undistort(pixels) if len(pixels) else pixels
    radius = estimate_radius(corner, top.line, right.line, ideal, config.fit.arc_exclusion_px)
    if radius is None:
        return None
    fit = config.fit
    return measure_arc(
        img, lens, corner, top.line, right.line, radius, expect_dark=dark,
        min_contrast_dn=config.limits.min_contrast_dn, search_px=search_px, level_samples=fit.level_samples,
        max_blur_sigma_px=fit.max_blur_sigma_px, robust_k=fit.robust_k, min_band_px=max(fit.min_robust_band_px, 0.3),
    )


def _feature_inset_px(profiles: dict[str, EdgeProfile], dark: bool) -> float:
    """How far the feature lies inside the wall's own edge (the default rule's step), mean of both edges (px)."""
    insets = []
    for prof in profiles.values():
        wall, step = pick_feature(prof.steps, dark, FeatureConfig()), prof.feature_step
        if wall is not None and step is not None:
            insets.append(step.offset_px - prof.steps[wall].offset_px)
    return float(np.mean(insets)) if insets else 0.0


def _radius_check(arc: ArcMeasurement, expected: CornerRadius, inset_px: float, lim: LimitsConfig) -> tuple[Check, str]:
    """The arc's radius against the opening's (less the feature's inset: its arc is concentric), and the refusal's words."""
    want = max(expected.radius_px - inset_px, 1.0)  # an inset past the radius: nothing is expected
    deviation = abs(arc.radius_px / want - 1.0)
    inset = f", less the feature's {inset_px:.0f} px inset" if abs(inset_px) >= 0.5 else ""
    words = (
        f"refused: arc radius {arc.radius_px:.0f} px, expected {want:.0f} px ({expected.source}{inset}), "
        f"off by {deviation:.0%} (limit: vision.limits.arc_radius_tolerance {lim.arc_radius_tolerance:g}): "
        "an edge line may lie on another edge beside the opening's (a shadow, a sealant band, a reflection), "
        "or the recipe's radius is not the opening's; check the image"
    )
    return at_most("arc radius deviation", deviation, lim.arc_radius_tolerance, Refusal.ARC_MISMATCH), words


def _feature_profile(
    image: NDArray[np.uint8], lens: Lens, name: EdgeName, line: Line2D, corner: F64, config: VisionConfig, dark: bool
) -> EdgeProfile | None:
    """The median profile across a seed line's straight part, beyond the arc, inside the ROI (None: no part inside)."""
    roi = config.roi
    margin = float(config.fit.border_margin_px)
    t_corner = float(line.along(corner[None, :])[0])
    start = t_corner + config.fit.arc_exclusion_px
    t = start + np.arange(0.0, 2.0 * (roi.width_px + roi.height_px), 8.0)
    raw = lens.distort(line.at(t))
    lo = np.array([roi.x_px + margin, roi.y_px + margin])
    hi = np.array([roi.x_px + roi.width_px - 1 - margin, roi.y_px + roi.height_px - 1 - margin])
    inside = np.all((raw >= lo) & (raw <= hi), axis=1)
    stop = int(np.argmin(inside)) if not np.all(inside) else len(inside)
    t = t[:stop]
    if len(t) < 2:
        return None
    along = np.linspace(t[0], t[-1], config.feature.cross_sections)
    return edge_profile(image, lens, line, name, along, dark, config.feature)


def _no_feature_message(name: str, profile: EdgeProfile, config: VisionConfig) -> str:
    f = config.feature
    steps = ", ".join(f"{s.offset_px:+.0f} px {s.change_dn:+.0f} DN ({s.fraction:.2f})" for s in profile.steps) or "none"
    return (
        f"the recipe's feature edge (step {f.index} counted from the {f.count_from}, at least "
        f"{f.min_step_fraction:g} of the range) is not on the {name} edge's profile; steps found "
        f"(place into the opening, change, share of the range): {steps}"
    )


def _taught_feature(
    prof: EdgeProfile, name: str, taught: TaughtProfile | None, feature: FeatureConfig, dark: bool
) -> tuple[EdgeProfile, str | None]:
    """The profile with the feature its taught neighbourhood finds (cellctl.vision.taught_profile), or why none.

    Unchanged where nothing was taught for this edge or ``feature.taught_profile`` is off.
    """
    edge = taught.edges.get(name) if taught is not None and feature.taught_profile else None
    if taught is None or edge is None:
        return prof, None
    if (problem := rule_problem(taught, feature)) is not None:
        return prof, problem
    k, why = match_taught(prof, edge, dark, feature)
    return (replace(prof, feature=k), None) if k is not None else (prof, f"refused: the {name} edge: {why}")


def _past_the_arc(config: VisionConfig, expected: CornerRadius | None) -> tuple[VisionConfig, SettingNames]:
    """``config`` with the edge points starting past the recipe's arc where it ends beyond ``fit.arc_exclusion_px``
    (a point on the arc bends the edge's line: the corner off by up to 0.6 px at 45 mm), and the refusals' names."""
    if expected is None:
        return config, SettingNames()
    exclusion = expected.exclusion_px(config.fit, config.limits)
    if exclusion <= config.fit.arc_exclusion_px:
        return config, SettingNames()
    fit = config.fit.model_copy(update={"arc_exclusion_px": exclusion})
    start = (f"the arc's end ({expected.source}, plus vision.limits.arc_radius_tolerance "
             f"{config.limits.arc_radius_tolerance:g}; vision.fit.arc_exclusion_px {config.fit.arc_exclusion_px:g} px is less)")
    return config.model_copy(update={"fit": fit}), SettingNames(start=start)


def _short_run_words(check: Check, expected: CornerRadius, top: EdgeMeasurement, right: EdgeMeasurement) -> str:
    """The corner sigma's refusal where the recipe's radius shortened the edges' straight runs (px)."""
    return (
        f"refused: {check.describe()}: the corner's arc ({expected.source}) leaves {top.quality.length_px:.0f} px of the top "
        f"edge and {right.quality.length_px:.0f} px of the right edge straight in view, and the corner is extrapolated "
        "from them; leave vision.shot_aim_mm out (the default aim moves the corner towards the image's upper right for a "
        "radius over about 31 mm at the paper's scale) or move it so both edges run on further, or check the shooting pose"
    )


def detect_corner(
    image: NDArray[np.uint8],
    lens: Lens,
    config: VisionConfig,
    expected_radius: CornerRadius | None = None,
    taught: TaughtProfile | None = None,
) -> CornerMeasurement:
    """Find the window's upper-right corner in a raw camera image.

    With ``expected_radius`` (the recipe's, cellctl.config.feature.corner_radius) the arc check
    also holds the fitted arc's radius to it (``limits.arc_radius_tolerance``). With ``taught``
    (the profiles teaching recorded; None for a set taught before they were) each edge's feature
    is the step whose neighbourhood is the taught one, and a profile that does not match is refused.

    Raises ValueError only for a wrong call (not a 2-D uint8 image of the lens's size, or an ROI
    outside the image); whatever the image shows, the answer is a CornerMeasurement, refused
    with a reason when a quality figure fails its limit.
    """
    img = lens.check_image(image)
    config.roi.check_inside(lens.width_px, lens.height_px)
    config, names = _past_the_arc(config, expected_radius)
    roi = config.roi
    exclusion = float(config.fit.arc_exclusion_px)
    coarse = find_coarse_corner(img, roi, config.coarse, config.opening_polarity, lens)
    if isinstance(coarse, CoarseFailure):
        refusal = Refusal.CORNER_NOT_FOUND if coarse.missing == "corner" else Refusal.EDGE_MISSING
        return CornerMeasurement(refusal, coarse.message, roi, exclusion, segments=coarse.segments)
    rng = np.random.default_rng(config.fit.seed)
    k = config.coarse.downscale
    seeds: dict[str, Line2D] = {}
    for name, pts in (("top", coarse.top_points), ("right", coarse.right_points)):
        if len(pts) < MIN_SEED_POINTS:
            return CornerMeasurement(
                Refusal.EDGE_MISSING, f"the {name} edge has only {len(pts)} edge pixels near its line", roi, exclusion,
                segments=coarse.segments,
            )
        ideal = lens.undistort(pts)
        mask = ransac_line(ideal, config.fit.ransac_band_px * k, config.fit.ransac_iterations, rng)
        if mask.sum() < MIN_SEED_POINTS:
            return CornerMeasurement(
                Refusal.EDGE_MISSING, f"no straight line through the {name} edge's pixels", roi, exclusion,
                segments=coarse.segments,
            )
        seeds[name] = fit_line(ideal[mask]).line.oriented(AWAY[name])
    corner = intersect(seeds["top"], seeds["right"])
    if corner is None:
        return CornerMeasurement(
            Refusal.CORNER_NOT_FOUND, "the two edges are parallel: no corner", roi, exclusion, segments=coarse.segments
        )
    profiles: dict[str, EdgeProfile] = {}
    for name in ("top", "right"):
        prof = _feature_profile(img, lens, name, seeds[name], corner, config, coarse.opening_darker)
        if prof is None:
            return CornerMeasurement(
                Refusal.EDGE_MISSING, too_near_border(lens, name, seeds[name], corner, config, names),  # type: ignore[arg-type]
                roi, exclusion, segments=coarse.segments, coarse_corner_px=corner,
            )
        prof, differs = _taught_feature(prof, name, taught, config.feature, coarse.opening_darker)
        profiles[name] = prof
        if differs is not None:
            return CornerMeasurement(
                Refusal.FEATURE_NOT_FOUND, differs, roi, exclusion, segments=coarse.segments, coarse_corner_px=corner
            )
        step = prof.feature_step
        if step is None:
            return CornerMeasurement(
                Refusal.FEATURE_NOT_FOUND, _no_feature_message(name, prof, config), roi, exclusion,
                segments=coarse.segments, coarse_corner_px=corner,
            )
        line = seeds[name]
        seeds[name] = Line2D(line.point + step.offset_px * into_opening(line, name), line.direction)
    corner = intersect(seeds["top"], seeds["right"])
    if corner is None:
        return CornerMeasurement(
            Refusal.CORNER_NOT_FOUND, "the two edges are parallel: no corner", roi, exclusion, segments=coarse.segments
        )

    edges: dict[str, EdgeMeasurement] = {}
    checks: list[Check] = []
    try:
        for name in ("top", "right"):
            edge, edge_checks = measure_edge(
                img, lens, name, seeds[name], corner, config, 2.0 * k + 1.0, coarse.opening_darker, rng, names  # type: ignore[arg-type]
            )
            edges[name] = replace(edge, profile=profiles[name])
            checks += edge_checks
        new_corner = intersect(edges["top"].line, edges["right"].line)
        if new_corner is None:
            raise Refused(Refusal.CORNER_NOT_FOUND, "the fitted edges are parallel: no corner")
        corner = new_corner
    except Refused as r:
        return CornerMeasurement(
            r.refusal, r.message, roi, exclusion, top=edges.get("top"), right=edges.get("right"),
            checks=tuple(checks), segments=coarse.segments, coarse_corner_px=corner,
        )

    top, right = edges["top"], edges["right"]
    corner_angle = float(np.arccos(np.clip(top.line.direction @ right.line.direction, -1.0, 1.0)))
    sigma = float(np.hypot(top.sigma_at_corner_px, right.sigma_at_corner_px))
    lim = config.limits
    checks += [
        at_most(
            "deviation from a right angle",
            abs(np.degrees(corner_angle) - 90.0),
            lim.perpendicular_tolerance_deg,
            Refusal.NOT_PERPENDICULAR,
            " deg",
        ),
    ]
    sigma_check = at_most("predicted corner sigma", sigma, lim.max_corner_sigma_px, Refusal.UNCERTAIN, " px")
    checks.append(sigma_check)
    arc = None
    notes: dict[str, str] = {}  # a check's name: the refusal's words, where they say more than describe()
    if expected_radius is not None and names != SettingNames():  # the radius moved the edges' start past its arc
        notes[sigma_check.name] = _short_run_words(sigma_check, expected_radius, top, right)
    if config.fit.check_arc:
        arc = _check_arc(img, lens, corner, top, right, coarse.edge_pixels, coarse.opening_darker, config, 2.0 * k + 1.0)
        if arc is None:
            checks.append(at_least("arc points", 0, 10, Refusal.ARC_NOT_SEEN))
        else:
            checks.append(at_least("arc coverage", arc.coverage_deg, lim.min_arc_coverage_deg, Refusal.ARC_NOT_SEEN, " deg"))
            if expected_radius is not None:
                inset = _feature_inset_px(profiles, coarse.opening_darker)
                radius_check, words = _radius_check(arc, expected_radius, inset, lim)
                checks.append(radius_check)
                notes[radius_check.name] = words
            checks += [
                at_most("top edge gap to the arc", abs(arc.gap_top_px), lim.max_arc_gap_px, Refusal.ARC_MISMATCH, " px"),
                at_most("right edge gap to the arc", abs(arc.gap_right_px), lim.max_arc_gap_px, Refusal.ARC_MISMATCH, " px"),
            ]
    raw = lens.distort(corner[None, :])[0]  # the ROI is in the raw image's pixels, the corner in the ideal image's
    inside = roi.x_px <= raw[0] <= roi.x_px + roi.width_px - 1 and roi.y_px <= raw[1] <= roi.y_px + roi.height_px - 1
    theta = 0.5 * (top.angle_rad + right.angle_rad)
    result = dict(
        roi=roi,
        arc_exclusion_px=exclusion,
        corner_px=corner,
        corner_raw_px=raw,
        theta_rad=theta,
        corner_angle_rad=corner_angle,
        corner_sigma_px=sigma,
        top=top,
        right=right,
        arc=arc,
        checks=tuple(checks),
        segments=coarse.segments,
        coarse_corner_px=corner,
    )
    if not inside:
        return CornerMeasurement(Refusal.CORNER_NOT_FOUND, "the corner lies outside the region of interest", **result)  # type: ignore[arg-type]
    failed = [c for c in checks if not c.passed]
    if failed:
        message = notes.get(failed[0].name, f"refused: {failed[0].describe()}")
        return CornerMeasurement(failed[0].refusal, message, **result)  # type: ignore[arg-type]
    return CornerMeasurement(None, "corner found", **result)  # type: ignore[arg-type]
