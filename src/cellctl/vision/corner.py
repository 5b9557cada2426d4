"""The window corner: two straight edges, their intersection (u, v) and angle theta (paper 4.2).

Pipeline, for one raw image:

1. Coarse (cellctl.vision.coarse): Canny and probabilistic Hough on the shrunk region of interest
   find the top and right edges beside the rounded upper-right corner, within a few pixels.
2. Seed lines: the Canny pixels near each coarse line are undistorted (the calibrated lens) and a
   RANSAC line through them gives each edge and a provisional corner in the ideal image.
3. Sub-pixel points: each seed line is sampled from ``arc_exclusion_px`` beyond the corner (the arc
   is left out) to the edge of the ROI, mapped into the raw image, and on every pixel column (top
   edge) or row (right edge) the edge crossing is measured to sub-pixel precision
   (cellctl.vision.subpixel). Profiles that are saturated, too faint, of the wrong polarity or
   on a disturbed background (a glare veil: see ``_background_consistent``) are left out; the
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

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from cellctl.config.vision import RoiConfig, VisionConfig
from cellctl.vision.arc import ArcMeasurement, estimate_radius, measure_arc
from cellctl.vision.coarse import CoarseFailure, find_coarse_corner
from cellctl.vision.lens import Lens
from cellctl.vision.lines import Line2D, LineFit, fit_line, intersect, line_angle_to_u, ransac_line
from cellctl.vision.quality import Check, EdgeQuality, Refusal, at_least, at_most
from cellctl.vision.subpixel import measure_crossings

F64 = NDArray[np.float64]
EdgeName = Literal["top", "right"]

_MIN_SEED_POINTS = 10
_AWAY = {"top": np.array([-1.0, 0.0]), "right": np.array([0.0, 1.0])}


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


def _check_image(image: object, lens: Lens) -> NDArray[np.uint8]:
    if not isinstance(image, np.ndarray):
        raise ValueError(f"image must be a numpy array, got {type(image).__name__}")
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"image must be 2-D uint8 grey values, got {image.dtype} with shape {image.shape}")
    if image.shape != (lens.height_px, lens.width_px):
        raise ValueError(
            f"image is {image.shape[1]} x {image.shape[0]} px but the lens is calibrated for "
            f"{lens.width_px} x {lens.height_px} px; use the calibration of this camera"
        )
    return image


def _edge_angle(name: EdgeName, direction: F64) -> float:
    if name == "top":
        return line_angle_to_u(direction)
    return line_angle_to_u(np.array([direction[1], -direction[0]]))


@dataclass(frozen=True)
class _Profiles:
    points_raw: F64
    contrast: F64
    blur: F64
    saturated: NDArray[np.bool_]
    valid: NDArray[np.bool_]
    level_before: F64
    level_after: F64


def _measure_profiles(
    image: NDArray[np.uint8],
    lens: Lens,
    line: Line2D,
    corner: F64,
    name: EdgeName,
    config: VisionConfig,
    search_px: float,
) -> _Profiles:
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
    empty = _Profiles(
        np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0, bool), np.zeros(0, bool), np.zeros(0), np.zeros(0)
    )
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
    return _Profiles(pts, cr.contrast, cr.blur_sigma_px, cr.saturated, cr.valid, cr.level_before, cr.level_after)


def _background_consistent(
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


def _robust_fit(points: F64, config: VisionConfig, rng: np.random.Generator) -> tuple[LineFit, NDArray[np.bool_]] | None:
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


class _Refused(Exception):
    """Internal: carries a refusal out of the pipeline (turned into a CornerMeasurement)."""

    def __init__(self, refusal: Refusal, message: str) -> None:
        super().__init__(message)
        self.refusal = refusal
        self.message = message


def _measure_edge(
    image: NDArray[np.uint8],
    lens: Lens,
    name: EdgeName,
    line: Line2D,
    corner: F64,
    config: VisionConfig,
    search_px: float,
    expect_dark: bool,
    rng: np.random.Generator,
) -> tuple[EdgeMeasurement, list[Check]]:
    lim = config.limits
    prof = _measure_profiles(image, lens, line, corner, name, config, search_px)
    n_prof = len(prof.valid)
    if n_prof == 0:
        raise _Refused(
            Refusal.EDGE_MISSING,
            f"the {name} edge has no straight part inside the region of interest beyond the arc "
            f"(arc_exclusion_px = {config.fit.arc_exclusion_px:g}); check the ROI and the corner radius",
        )
    # Contrast sign seen along growing v (top edge) or u (right edge): opening darker means the
    # level falls into the opening below the top edge (negative) and rises out of it to the
    # right of the right edge (positive).
    sign = (-1.0 if name == "top" else 1.0) * (1.0 if expect_dark else -1.0)
    valid = prof.valid
    contrast_dn = float(np.median(sign * prof.contrast[valid])) if np.any(valid) else 0.0
    saturated_fraction = float(np.mean(prof.saturated)) if n_prof else 0.0
    good = valid & ~prof.saturated & (sign * prof.contrast >= 0.5 * lim.min_contrast_dn)
    good &= prof.blur <= config.fit.max_blur_sigma_px
    flat = _background_consistent((prof.level_before, prof.level_after), good, config.fit.background_tolerance)
    uneven = int(np.sum(good & ~flat))
    good &= flat
    checks = [
        at_least(f"{name} edge contrast", contrast_dn, lim.min_contrast_dn, Refusal.LOW_CONTRAST, " DN"),
        at_most(f"{name} edge saturated share", saturated_fraction, lim.max_saturated_fraction, Refusal.SATURATED),
    ]
    pts_raw = prof.points_raw[good]
    blur = float(np.median(prof.blur[good])) if np.any(good) else float("nan")
    if len(pts_raw) < max(_MIN_SEED_POINTS, 2):
        checks.append(at_least(f"{name} edge points", len(pts_raw), lim.min_edge_points, Refusal.EDGE_MISSING))
        _raise_first(checks)
        raise _Refused(Refusal.EDGE_MISSING, f"the {name} edge gave only {len(pts_raw)} sub-pixel points")
    pts_ideal = lens.undistort(pts_raw)
    fitted = _robust_fit(pts_ideal, config, rng)
    if fitted is None:
        raise _Refused(Refusal.EDGE_MISSING, f"no line fits the {name} edge's points")
    fit, mask = fitted
    new_line = fit.line.oriented(_AWAY[name])
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


def _raise_first(checks: list[Check]) -> None:
    for c in checks:
        if not c.passed:
            raise _Refused(c.refusal, f"refused: {c.describe()}")


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


def detect_corner(image: NDArray[np.uint8], lens: Lens, config: VisionConfig) -> CornerMeasurement:
    """Find the window's upper-right corner in a raw camera image.

    Raises ValueError only for a wrong call (not a 2-D uint8 image of the lens's size, or an ROI
    outside the image); whatever the image shows, the answer is a CornerMeasurement, refused
    with a reason when a quality figure fails its limit.
    """
    img = _check_image(image, lens)
    config.roi.check_inside(lens.width_px, lens.height_px)
    roi = config.roi
    exclusion = float(config.fit.arc_exclusion_px)
    coarse = find_coarse_corner(img, roi, config.coarse, config.opening_polarity)
    if isinstance(coarse, CoarseFailure):
        refusal = Refusal.CORNER_NOT_FOUND if coarse.missing == "corner" else Refusal.EDGE_MISSING
        return CornerMeasurement(refusal, coarse.message, roi, exclusion, segments=coarse.segments)
    rng = np.random.default_rng(config.fit.seed)
    k = config.coarse.downscale
    seeds: dict[str, Line2D] = {}
    for name, pts in (("top", coarse.top_points), ("right", coarse.right_points)):
        if len(pts) < _MIN_SEED_POINTS:
            return CornerMeasurement(
                Refusal.EDGE_MISSING, f"the {name} edge has only {len(pts)} edge pixels near its line", roi, exclusion,
                segments=coarse.segments,
            )
        ideal = lens.undistort(pts)
        mask = ransac_line(ideal, config.fit.ransac_band_px * k, config.fit.ransac_iterations, rng)
        if mask.sum() < _MIN_SEED_POINTS:
            return CornerMeasurement(
                Refusal.EDGE_MISSING, f"no straight line through the {name} edge's pixels", roi, exclusion,
                segments=coarse.segments,
            )
        seeds[name] = fit_line(ideal[mask]).line.oriented(_AWAY[name])
    corner = intersect(seeds["top"], seeds["right"])
    if corner is None:
        return CornerMeasurement(
            Refusal.CORNER_NOT_FOUND, "the two edges are parallel: no corner", roi, exclusion, segments=coarse.segments
        )

    edges: dict[str, EdgeMeasurement] = {}
    checks: list[Check] = []
    try:
        for name in ("top", "right"):
            edge, edge_checks = _measure_edge(
                img, lens, name, seeds[name], corner, config, 2.0 * k + 1.0, coarse.opening_darker, rng  # type: ignore[arg-type]
            )
            edges[name] = edge
            checks += edge_checks
        new_corner = intersect(edges["top"].line, edges["right"].line)
        if new_corner is None:
            raise _Refused(Refusal.CORNER_NOT_FOUND, "the fitted edges are parallel: no corner")
        corner = new_corner
    except _Refused as r:
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
        at_most("predicted corner sigma", sigma, lim.max_corner_sigma_px, Refusal.UNCERTAIN, " px"),
    ]
    arc = None
    if config.fit.check_arc:
        arc = _check_arc(img, lens, corner, top, right, coarse.edge_pixels, coarse.opening_darker, config, 2.0 * k + 1.0)
        if arc is None:
            checks.append(at_least("arc points", 0, 10, Refusal.ARC_NOT_SEEN))
        else:
            checks += [
                at_least("arc coverage", arc.coverage_deg, lim.min_arc_coverage_deg, Refusal.ARC_NOT_SEEN, " deg"),
                at_most("top edge gap to the arc", abs(arc.gap_top_px), lim.max_arc_gap_px, Refusal.ARC_MISMATCH, " px"),
                at_most("right edge gap to the arc", abs(arc.gap_right_px), lim.max_arc_gap_px, Refusal.ARC_MISMATCH, " px"),
            ]
    inside = roi.x_px <= corner[0] <= roi.x_px + roi.width_px - 1 and roi.y_px <= corner[1] <= roi.y_px + roi.height_px - 1
    theta = 0.5 * (top.angle_rad + right.angle_rad)
    result = dict(
        roi=roi,
        arc_exclusion_px=exclusion,
        corner_px=corner,
        corner_raw_px=lens.distort(corner[None, :])[0],
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
        return CornerMeasurement(failed[0].refusal, f"refused: {failed[0].describe()}", **result)  # type: ignore[arg-type]
    return CornerMeasurement(None, "corner found", **result)  # type: ignore[arg-type]
