"""One straight edge beside the corner: sub-pixel points on its straight part and the robust line.

Each edge's seed line (in the ideal image) is sampled from ``arc_exclusion_px`` beyond the corner
to the border of the region of interest, mapped into the raw image, and on every pixel column
(top edge) or row (right edge) the crossing is measured to sub-pixel precision
(cellctl.vision.subpixel). Profiles that are saturated, too faint, of the wrong polarity or on a
disturbed background are left out; RANSAC and a robust least-squares refit keep the points of the
edge and drop those of a mark or a spot crossing it. Every figure is held to its limit
(cellctl.config.vision.LimitsConfig); a failing one is raised as :class:`Refused`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from cellctl.config.vision import VisionConfig
from cellctl.vision.lens import Lens
from cellctl.vision.lines import Line2D, LineFit, fit_line, line_angle_to_u, ransac_line
from cellctl.vision.profile import EdgeProfile
from cellctl.vision.quality import Check, EdgeQuality, Refusal, Refused, at_least, at_most
from cellctl.vision.subpixel import EdgeCrossings, measure_crossings, shape_bump

F64 = NDArray[np.float64]
EdgeName = Literal["top", "right"]

MIN_SEED_POINTS = 10
BUMP_NOISE_SIGMAS = 8.0  # the median profile's noise alone stays under about 4 of its sigmas (max over the window)
AWAY = {"top": np.array([-1.0, 0.0]), "right": np.array([0.0, 1.0])}
"""Each edge's line direction points away from the corner: left for the top edge, down for the right."""


@dataclass(frozen=True)
class EdgeMeasurement:
    """One straight edge beside the corner.

    ``line`` is in the ideal (undistorted) image, its direction pointing away from the corner.
    ``angle_rad`` is the edge's rotation: the top edge's angle to the u axis, the right edge's
    angle to the v axis. ``points_raw``/``points_ideal`` are the sub-pixel edge points (raw and
    undistorted), ``inliers`` marks those the line was fitted to.
    """

    name: EdgeName
    line: Line2D
    angle_rad: float
    points_raw: F64
    points_ideal: F64
    inliers: NDArray[np.bool_]
    quality: EdgeQuality
    sigma_at_corner_px: float
    profile: EdgeProfile | None = None


@dataclass(frozen=True)
class SettingNames:
    """Where the settings a refusal names live: the corner detector's, or the inspection's (vision.gap)."""

    start: str = "vision.fit.arc_exclusion_px"
    max_blur: str = "vision.fit.max_blur_sigma_px"
    max_bump: str = "vision.fit.max_edge_bump"


INSPECTION_SETTINGS = SettingNames("vision.gap.start_px", "vision.gap.max_blur_sigma_px", "vision.gap.max_edge_bump")


def _edge_angle(name: EdgeName, direction: F64) -> float:
    if name == "top":
        return line_angle_to_u(direction)
    return line_angle_to_u(np.array([direction[1], -direction[0]]))


def _measure_profiles(
    image: NDArray[np.uint8],
    lens: Lens,
    line: Line2D,
    corner: F64,
    name: EdgeName,
    config: VisionConfig,
    search_px: float,
) -> tuple[F64, EdgeCrossings]:
    """Sub-pixel crossings on every pixel column (top edge) or row (right edge) of its straight part."""
    roi = config.roi
    fit = config.fit
    margin = float(fit.border_margin_px)
    t = np.arange(fit.arc_exclusion_px, fit.arc_exclusion_px + 2.0 * (roi.width_px + roi.height_px), 1.0)
    ideal = corner + t[:, None] * line.direction
    lo = np.array([roi.x_px + margin, roi.y_px + margin])
    hi = np.array([roi.x_px + roi.width_px - 1 - margin, roi.y_px + roi.height_px - 1 - margin])
    # Points far outside the image are cut before distorting them (the model is only valid near it).
    near = np.all((ideal > lo - 200.0) & (ideal < hi + 200.0), axis=1)
    stop = int(np.argmin(near)) if not np.all(near) else len(near)
    ideal = ideal[:stop]
    empty = (np.zeros((0, 2)), EdgeCrossings.empty())
    if len(ideal) < 2:
        return empty
    raw = lens.distort(ideal)
    inside = np.all((raw >= lo) & (raw <= hi), axis=1)
    if not inside[0]:
        return empty
    stop = int(np.argmin(inside)) if not np.all(inside) else len(inside)
    raw = raw[:stop]
    if len(raw) < 2:
        return empty
    axis = 0 if name == "top" else 1  # the coordinate that steps from profile to profile
    order = np.argsort(raw[:, axis])
    s = raw[order, axis]
    e = raw[order, 1 - axis]
    fixed = np.arange(int(np.ceil(s[0])), int(np.floor(s[-1])) + 1, dtype=np.int64)
    if len(fixed) == 0:
        return empty
    expected = np.interp(fixed.astype(float), s, e)
    cr = measure_crossings(
        image,
        fixed,
        expected,
        along_rows=(name == "right"),
        search_px=search_px,
        level_samples=fit.level_samples,
        max_blur_sigma_px=fit.max_blur_sigma_px,
    )
    if name == "top":
        pts = np.column_stack([fixed.astype(float), cr.position])
    else:
        pts = np.column_stack([cr.position, fixed.astype(float)])
    return pts, cr


def too_near_border(
    lens: Lens, name: EdgeName, line: Line2D, corner: F64, config: VisionConfig, names: SettingNames = SettingNames()
) -> str:
    """The refusal's words when an edge's straight part (beyond the arc) is not inside the ROI."""
    roi, fit = config.roi, config.fit
    start = lens.distort((corner + fit.arc_exclusion_px * line.direction)[None, :])[0]
    m = float(fit.border_margin_px)
    out = {
        "left": start[0] < roi.x_px + m, "right": start[0] > roi.x_px + roi.width_px - 1 - m,
        "top": start[1] < roi.y_px + m, "bottom": start[1] > roi.y_px + roi.height_px - 1 - m,
    }
    sides = " and ".join(k for k, v in out.items() if v) or {"top": "left", "right": "bottom"}[name]
    return (
        f"refused: the corner at ({corner[0]:.0f}, {corner[1]:.0f}) px lies too near the {sides} border of the "
        f"region of interest: the {name} edge's straight part, from {names.start} = "
        f"{fit.arc_exclusion_px:g} px beyond the corner, is not inside it; re-aim the camera (check the "
        "shooting pose and vision.roi) so that the corner lies nearer the image centre"
    )


def background_consistent(
    levels: tuple[F64, F64], mask: NDArray[np.bool_], tolerance: float
) -> NDArray[np.bool_]:
    """Profiles whose darker-to-brighter plateau ratio matches the edge's undisturbed one.

    Lighting (vignetting, a gradient, exposure) multiplies the wall's and the opening's levels
    alike, so their ratio stays the same all along an edge. Light added on top (a glare spot, a
    reflection) or taken from one side only (a shadow) changes it; such a profile's background is
    not flat and its crossing is biased, so it is left out. The undisturbed ratio is the mode of
    the ratios (the densest window), not their median: a glare spot may cover most of a short
    edge, but it spreads its profiles over a range of ratios. A profile is kept within
    ``tolerance`` of it, or 4 sigmas of the ratio's noise if that is larger (the noise is
    taken from differences between neighbouring profiles, which a smooth disturbance leaves small).
    """
    keep = mask.copy()
    if mask.sum() < 20:
        return keep
    a, b = levels
    ratio = np.minimum(a, b) / np.maximum(np.maximum(a, b), 1e-9)
    r = ratio[mask]  # in the profiles' order along the edge
    sigma = 1.4826 * float(np.median(np.abs(np.diff(r)))) / np.sqrt(2.0)
    band = max(4.0 * sigma, tolerance)
    srt = np.sort(r)
    ends = np.searchsorted(srt, srt + 2.0 * band, side="right")
    i = int(np.argmax(ends - np.arange(len(srt))))
    reference = float(np.median(srt[i : ends[i]]))
    keep &= np.abs(ratio - reference) <= band
    return keep


def robust_line_fit(points: F64, config: VisionConfig, rng: np.random.Generator) -> tuple[LineFit, NDArray[np.bool_]] | None:
    """RANSAC, then least squares on the inliers within a robust band (k x MAD sigma), twice."""
    fit_cfg = config.fit
    mask = ransac_line(points, fit_cfg.subpixel_band_px, fit_cfg.ransac_iterations, rng)
    if mask.sum() < 2:
        return None
    fit = fit_line(points[mask])
    for _ in range(2):
        r = fit.line.signed_distance(points)
        ri = r[mask]
        sigma = 1.4826 * float(np.median(np.abs(ri - np.median(ri))))
        band = max(fit_cfg.robust_k * sigma, fit_cfg.min_robust_band_px)
        new_mask = np.abs(r) < band
        if new_mask.sum() < 2:
            break
        mask = new_mask
        fit = fit_line(points[mask])
    return fit, mask


def _bow(line: Line2D, points: F64) -> tuple[float, float]:
    """Sagitta (px) of a parabola fitted to the residuals over the points' span, and the span."""
    t = line.along(points)
    r = line.signed_distance(points)
    span = float(t.max() - t.min()) if len(t) else 0.0
    if len(t) < 5 or span <= 0:
        return 0.0, span
    tn = (t - (t.max() + t.min()) / 2.0) / (span / 2.0)
    c2 = float(np.polyfit(tn, r, 2)[0])
    return abs(c2), span


def measure_edge(
    image: NDArray[np.uint8],
    lens: Lens,
    name: EdgeName,
    line: Line2D,
    corner: F64,
    config: VisionConfig,
    search_px: float,
    expect_dark: bool,
    rng: np.random.Generator,
    names: SettingNames = SettingNames(),
) -> tuple[EdgeMeasurement, list[Check]]:
    """The edge's sub-pixel points and robust line with its checks; raises Refused (naming ``names``) when it has too few points."""
    lim = config.limits
    points_all, prof = _measure_profiles(image, lens, line, corner, name, config, search_px)
    n_prof = len(prof.valid)
    if n_prof == 0:
        raise Refused(Refusal.EDGE_MISSING, too_near_border(lens, name, line, corner, config, names))
    # Contrast sign seen along growing v (top edge) or u (right edge): opening darker means the
    # level falls into the opening below the top edge (negative) and rises out of it to the
    # right of the right edge (positive).
    sign = (-1.0 if name == "top" else 1.0) * (1.0 if expect_dark else -1.0)
    valid = prof.valid
    contrast_dn = float(np.median(sign * prof.contrast[valid])) if np.any(valid) else 0.0
    saturated_fraction = float(np.mean(prof.saturated)) if n_prof else 0.0
    usable = valid & ~prof.saturated & (sign * prof.contrast >= 0.5 * lim.min_contrast_dn)
    good = usable & (prof.blur_sigma_px <= config.fit.max_blur_sigma_px)
    flat = background_consistent((prof.level_before, prof.level_after), good, config.fit.background_tolerance)
    uneven = int(np.sum(good & ~flat))
    good &= flat
    checks = [
        at_least(f"{name} edge contrast", contrast_dn, lim.min_contrast_dn, Refusal.LOW_CONTRAST, " DN"),
        at_most(f"{name} edge saturated share", saturated_fraction, lim.max_saturated_fraction, Refusal.SATURATED),
    ]
    pts_raw = points_all[good]
    blur = float(np.median(prof.blur_sigma_px[good])) if np.any(good) else float("nan")
    if len(pts_raw) < max(lim.min_edge_points, MIN_SEED_POINTS, 2):
        words = _blurred_words(name, prof.blur_sigma_px, usable, len(pts_raw), config, names)
        if words is not None:
            raise_first(checks)  # a faint or saturated edge is named first, as before
            raise Refused(Refusal.EDGE_MISSING, words)
    if len(pts_raw) < max(MIN_SEED_POINTS, 2):
        checks.append(at_least(f"{name} edge points", len(pts_raw), lim.min_edge_points, Refusal.EDGE_MISSING))
        raise_first(checks)
        raise Refused(Refusal.EDGE_MISSING, f"the {name} edge gave only {len(pts_raw)} sub-pixel points")
    _check_bump(name, prof.normalised[good] if len(prof.normalised) else prof.normalised, checks, config, names)
    pts_ideal = lens.undistort(pts_raw)
    fitted = robust_line_fit(pts_ideal, config, rng)
    if fitted is None:
        raise Refused(Refusal.EDGE_MISSING, f"no line fits the {name} edge's points")
    fit, mask = fitted
    new_line = fit.line.oriented(AWAY[name])
    bow, span = _bow(new_line, pts_ideal[mask])
    quality = EdgeQuality(
        profiles=n_prof,
        points=int(len(pts_raw)),
        inliers=int(mask.sum()),
        rms_px=fit.rms_px,
        contrast_dn=contrast_dn,
        blur_sigma_px=blur,
        bow_px=bow,
        length_px=span,
        saturated_fraction=saturated_fraction,
        sigma_angle_rad=fit.sigma_angle_rad,
        uneven_background=uneven,
    )
    checks += [
        at_least(f"{name} edge points", quality.inliers, lim.min_edge_points, Refusal.EDGE_MISSING),
        at_most(f"{name} edge fit RMS", quality.rms_px, lim.max_fit_rms_px, Refusal.POOR_FIT, " px"),
        at_least(f"{name} edge inlier share", quality.inlier_fraction, lim.min_inlier_fraction, Refusal.POOR_FIT),
        at_most(f"{name} edge bow", quality.bow_px, lim.max_bow_px, Refusal.EDGE_BENT, " px"),
    ]
    # Offset uncertainty of the line where it meets the corner (extrapolated from the centroid).
    t_c = float(new_line.along(corner[None, :])[0])
    sigma_c = float(np.hypot(fit.sigma_offset_px, t_c * fit.sigma_angle_rad))
    edge = EdgeMeasurement(
        name, new_line, _edge_angle(name, new_line.direction), pts_raw, pts_ideal, mask, quality, sigma_c
    )
    return edge, checks


def _blurred_words(
    name: EdgeName, spread: F64, usable: NDArray[np.bool_], points: int, config: VisionConfig, names: SettingNames
) -> str | None:
    """The refusal's words when most usable profiles were dropped for blur (None: blur is not the cause)."""
    limit = config.fit.max_blur_sigma_px
    blurred = usable & (spread > limit)
    if not np.any(blurred) or 2 * int(blurred.sum()) <= int(usable.sum()):
        return None
    return (
        f"refused: the {name} edge is blurred: its spread is {float(np.median(spread[blurred])):.1f} px on "
        f"{int(blurred.sum())} of {int(usable.sum())} profiles, over {names.max_blur} = {limit:g} px, "
        f"leaving {points} edge points (limit: at least {config.limits.min_edge_points}); check the camera's focus "
        "and that the robot has come to rest before the shot (motion blur)"
    )


def _check_bump(name: EdgeName, normalised: F64, checks: list[Check], config: VisionConfig, names: SettingNames) -> None:
    """Refuse an edge whose mean shape is not one step: a highlight or a glint beside it biases every crossing."""
    bump, noise = shape_bump(normalised, config.fit.level_samples)
    limit = max(config.fit.max_edge_bump, BUMP_NOISE_SIGMAS * noise)
    if bump <= limit:
        return
    raise_first(checks)  # a faint or saturated edge is named first
    raise Refused(
        Refusal.POOR_FIT,
        f"refused: the {name} edge's profile is not one clean step: it overshoots or turns back by {bump:.2f} of its "
        f"contrast beside the edge (limit: {limit:.2f}, the larger of {names.max_bump} = {config.fit.max_edge_bump:g} and "
        f"{BUMP_NOISE_SIGMAS:g} sigmas of the profile's noise); a highlight, a glint or a thin line runs "
        "along the edge and would shift it; check the lighting (reflections of the ring light on the hem or the "
        "glass's arris) and the edge for paint lines or seal lips",
    )


def raise_first(checks: list[Check]) -> None:
    for c in checks:
        if not c.passed:
            raise Refused(c.refusal, f"refused: {c.describe()}")
