"""The large-radius corner: the arc itself as the feature (issue 21; paper 4.2, "fit the arc, then
derive the lines from its centre, radius and tangent directions").

With a corner radius of 100-200 mm the straight edges lie outside the view. Pipeline, one raw image:

1. Coarse: Canny on the shrunk ROI; each edge pixel (undistorted) votes for the centre one expected
   radius behind it along its gradient (a Hough circle of known radius); the pixels of the strongest
   vote give a RANSAC circle within 20 % of the expected radius.
2. Sub-pixel points: on every pixel column or row crossing that arc (the one closer to its normal),
   the edge crossing (cellctl.vision.subpixel); profiles on an uneven background (glare) are left
   out; the rest are undistorted with the lens. Only the corner's quarter is profiled (normals
   from up to right, give or take ``tangent.max_tilt_deg``): beyond the tangent points the outline
   runs straight, and the circle continued there crosses the inner bands' straight edges.
3. Fit: RANSAC, then geometric least squares within a robust band (cellctl.vision.arc); the centre
   and radius with their 1-sigma from the fit's covariance.
4. Orientation (cellctl.vision.arc_tangent): from the straight edges beyond the arc's ends where
   they are in view, each checked tangent to the circle; else None with the reason.

Every figure is checked against :class:`cellctl.config.arc_vision.ArcLimitsConfig`; the first
failing check makes the answer a refusal (a value with the reason), not an exception. A clean arc
refused only for its coverage or its centre's sigma, where the arc runs out of the ROI, keeps its
centre as ``coarse_corner_px``: enough to re-aim the camera (as the corner method's coarse find).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.config.arc_vision import ArcCornerConfig
from cellctl.vision.arc import arc_crossings, fit_circle, ransac_circle, robust_circle
from cellctl.vision.arc_profile import arc_profile
from cellctl.vision.arc_tangent import ArcOrientation, measure_orientation
from cellctl.vision.edge import background_consistent
from cellctl.vision.lens import Lens
from cellctl.vision.quality import Check, Refusal, at_least, at_most

F64 = NDArray[np.float64]

__all__ = ["ArcCornerMeasurement", "detect_arc_corner", "measure_circle"]

_COARSE_RADIUS_TOLERANCE = 0.2  # seed circles within this share of the expected radius
_SPAN_MARGIN_RAD = np.radians(2.0)  # profiles taken this far beyond the seed's ends
# Refused for these alone (the image cuts the arc short), a clean arc still aims the camera.
_SHORT_ARC_CHECKS = ("min arc coverage", "max predicted centre sigma")
_END_REACH_RAD = 2.0 * _SPAN_MARGIN_RAD  # the arc leaves the ROI within this beyond its inliers' ends (the trims)


@dataclass(frozen=True)
class ArcCornerMeasurement:
    """The arc detector's answer: the arc's centre with its quality figures, or a refusal.

    ``centre_px`` (u, v) is in the ideal image (camera matrix A, no distortion): the feature point
    (the virtual sharp corner is ``centre + R (1, -1)`` turned by theta for a square corner).
    ``radius_px`` is in square px (fx on both axes: the arc is an ellipse in the ideal image
    where fy differs, its vertical half-axis ``radius_px * fy / fx``), the 1-sigmas are px;
    ``coverage_deg`` the angle the inliers span about
    the centre (90 deg is the whole arc of a square corner). ``orientation`` holds theta or why
    there is none. ``checks`` lists every figure against its limit; ``refusal`` is the reason of
    the first failing one.
    """

    refusal: Refusal | None
    message: str
    centre_px: F64 | None = None
    centre_raw_px: F64 | None = None
    radius_px: float | None = None
    centre_sigma_px: float | None = None
    radius_sigma_px: float | None = None
    coverage_deg: float | None = None
    rms_px: float | None = None
    orientation: ArcOrientation | None = None
    checks: tuple[Check, ...] = ()
    points_ideal: F64 = field(default_factory=lambda: np.zeros((0, 2)))
    inliers: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    edge_pixels: F64 = field(default_factory=lambda: np.zeros((0, 2)))  # the image's Canny pixels (ideal px)
    coarse_corner_px: F64 | None = None
    """The centre (ideal px) of an arc refused only because the image cuts it short (coverage, centre
    sigma): the arc runs out of the ROI, every other figure passed. Enough to re-aim the camera."""

    @property
    def ok(self) -> bool:
        return self.refusal is None

    @property
    def failed(self) -> Check | None:
        """The check that made the refusal (None when accepted or refused before any check)."""
        return next((c for c in self.checks if not c.passed), None)


@dataclass(frozen=True)
class _Seed:
    centre: F64
    radius: float
    mid: F64  # unit direction from the centre to the middle of the seed's arc
    span: tuple[float, float]  # angles (rad) of the seed's ends about ``mid``
    pixels: F64  # every Canny pixel, ideal px


def _angles(points: F64, centre: F64, mid: F64) -> F64:
    """Angles (rad) of points about ``centre``, measured from the direction ``mid`` (towards +v from +u)."""
    d = points - centre
    return np.arctan2(mid[0] * d[:, 1] - mid[1] * d[:, 0], d @ mid)


def _seed(img: NDArray[np.uint8], lens: Lens, config: ArcCornerConfig, rng: np.random.Generator) -> _Seed | str:
    """Step 1: a circle through the Canny pixels of the arc (ideal px), or why there is none."""
    roi, s = config.roi, config.search
    k = int(s.downscale)
    crop = img[roi.y_px : roi.y_px + roi.height_px, roi.x_px : roi.x_px + roi.width_px]
    small = cv2.resize(crop, (crop.shape[1] // k, crop.shape[0] // k), interpolation=cv2.INTER_AREA) if k > 1 else crop
    if s.blur_sigma_px > 0:
        small = cv2.GaussianBlur(small, (0, 0), s.blur_sigma_px)
    edges = cv2.Canny(small, s.canny_low, s.canny_high, L2gradient=True)
    ys, xs = np.nonzero(edges)
    if len(xs) < 20:
        return f"only {len(xs)} edge pixels in the region of interest"
    f = small.astype(np.float32)
    g = np.column_stack([cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3)[ys, xs], cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3)[ys, xs]])
    g = g.astype(np.float64) / np.maximum(np.hypot(g[:, 0], g[:, 1]), 1e-9)[:, None]
    raw = (np.column_stack([xs, ys]).astype(np.float64) + 0.5) * k - 0.5 + np.array([roi.x_px, roi.y_px], dtype=float)
    pixels = lens.undistort(raw)
    R = float(config.expected_radius_px)
    # The gradient points from dark to bright; the centre lies inside the opening.
    votes = pixels + (-R if config.opening_polarity == "darker" else R) * g
    size = max(s.vote_bin_fraction * R, 2.0 * k)
    lo = votes.min(axis=0)
    cells = np.floor((votes - lo) / size).astype(np.int64)
    acc = np.zeros(tuple(cells.max(axis=0)[::-1] + 3), dtype=np.float64)
    np.add.at(acc, (cells[:, 1] + 1, cells[:, 0] + 1), 1.0)
    acc = cv2.boxFilter(acc, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    iy, ix = np.unravel_index(int(np.argmax(acc)), acc.shape)
    peak = lo + (np.array([ix, iy], dtype=float) - 0.5) * size
    dist = np.hypot(*(pixels - peak).T)
    pick = (np.hypot(*(votes - peak).T) < 2.0 * size) & (np.abs(dist - R) < _COARSE_RADIUS_TOLERANCE * R)
    if pick.sum() < 20:
        return f"no arc of about {R:.0f} px radius among the edge pixels"
    band = s.ransac_band_px * k
    mask = ransac_circle(pixels[pick], R, band, s.ransac_iterations, rng, _COARSE_RADIUS_TOLERANCE)
    if mask.sum() < 20:
        return f"no arc of about {R:.0f} px radius among the edge pixels"
    centre, radius = fit_circle(pixels[pick][mask])
    on = np.abs(np.hypot(*(pixels - centre).T) - radius) < band
    centre, radius = fit_circle(pixels[on])
    d = pixels[on] - centre
    mean = d.sum(axis=0)
    mid = mean / max(float(np.linalg.norm(mean)), 1e-9)
    ang = _angles(pixels[on], centre, mid)
    return _Seed(centre, float(radius), mid, (float(ang.min()), float(ang.max())), pixels)


def in_quarter(normals: F64, max_tilt_deg: float) -> NDArray[np.bool_]:
    """Normals (unit, ideal image: u right, v down) within the upper-right corner's quarter: from up
    (0, -1) to right (1, 0), each end widened by ``max_tilt_deg`` (the corner's turn in the image)."""
    phi = np.degrees(np.arctan2(normals[:, 0], -normals[:, 1]))  # 0 up, 90 right
    return (phi >= -max_tilt_deg) & (phi <= 90.0 + max_tilt_deg)


def _inside_roi(lens: Lens, ideal: F64, config: ArcCornerConfig) -> NDArray[np.bool_]:
    """Ideal points whose raw image lies inside the ROI less its border margin."""
    roi, m = config.roi, float(config.search.border_margin_px)
    raw = lens.distort(ideal) if len(ideal) else np.zeros((0, 2))
    lo = np.array([roi.x_px + m, roi.y_px + m])
    hi = np.array([roi.x_px + roi.width_px - 1 - m, roi.y_px + roi.height_px - 1 - m])
    return np.all((raw >= lo) & (raw <= hi), axis=1)


def _runs_out(lens: Lens, config: ArcCornerConfig, c_sq: F64, R: float, mid: F64, ends: tuple[float, float]) -> bool:
    """Whether the circle (square px) leaves the ROI just beyond an end of the inliers (angles about ``mid``, rad)."""
    perp = np.array([-mid[1], mid[0]])
    t = np.array([ends[0] - _END_REACH_RAD, ends[1] + _END_REACH_RAD])
    beyond = lens.from_square(c_sq + R * (np.cos(t)[:, None] * mid + np.sin(t)[:, None] * perp))
    return not bool(_inside_roi(lens, beyond, config).all())


def _trim_ends(
    pts: F64, c: F64, R: float, inl: NDArray[np.bool_], robust_k: float, min_band_px: float, mid: F64
) -> tuple[F64, float, NDArray[np.bool_]]:
    """Leave out the ends of the inliers where a straight edge may go on from the arc, and refit.

    A tangent straight edge leaves the circle by t^2 / 2R, so it stays within the robust band b
    for t up to sqrt(2 b R): its points there are inliers that pull the circle outwards. Dropping
    1.5 times that angle, sqrt(2 b / R), at each end of the inliers leaves only the arc.
    """
    r = np.hypot(*(pts[inl] - c).T) - R
    band = max(robust_k * 1.4826 * float(np.median(np.abs(r - np.median(r)))), min_band_px)
    ang = _angles(pts, c, mid)
    delta = 1.5 * np.sqrt(2.0 * band / R)
    trimmed = inl & (ang > ang[inl].min() + delta) & (ang < ang[inl].max() - delta)
    if trimmed.sum() < 10:
        return c, R, inl
    c2, R2 = fit_circle(pts[trimmed])
    return c2, float(R2), trimmed


def _covariance(points: F64, centre: F64, radius: float) -> tuple[float, float]:
    """1-sigma of the centre (RMS of u and v, px) and of the radius from the geometric fit's Jacobian."""
    d = points - centre
    dist = np.hypot(d[:, 0], d[:, 1])
    r = dist - radius
    J = np.column_stack([-d[:, 0] / dist, -d[:, 1] / dist, -np.ones(len(dist))])
    s2 = float(np.sum(r * r)) / max(len(r) - 3, 1)
    cov = s2 * np.linalg.inv(J.T @ J)
    return float(np.sqrt(cov[0, 0] + cov[1, 1])), float(np.sqrt(cov[2, 2]))


def detect_arc_corner(image: NDArray[np.uint8], lens: Lens, config: ArcCornerConfig) -> ArcCornerMeasurement:
    """Find the centre (u, v) of the upper-right corner's arc in a raw image (ideal px).

    Raises ValueError only for a wrong call (not a 2-D uint8 image of the lens's size, or an ROI
    outside the image); whatever the image shows, the answer is an ArcCornerMeasurement, refused
    with a reason when a quality figure fails its limit.
    """
    img = lens.check_image(image)
    config.roi.check_inside(lens.width_px, lens.height_px)
    rng = np.random.default_rng(config.search.seed)
    seed = _seed(img, lens, config, rng)
    if isinstance(seed, str):
        return ArcCornerMeasurement(Refusal.ARC_NOT_SEEN, seed)
    # Step 2: profiles across the seed arc (every 0.5 px of it), ordered along the arc.
    a0, a1 = seed.span[0] - _SPAN_MARGIN_RAD, seed.span[1] + _SPAN_MARGIN_RAD
    t = np.linspace(a0, a1, max(int((a1 - a0) * seed.radius * 2.0), 8))
    perp = np.array([-seed.mid[1], seed.mid[0]])
    normals = np.cos(t)[:, None] * seed.mid + np.sin(t)[:, None] * perp
    normals = normals[in_quarter(normals, config.tangent.max_tilt_deg)]
    if len(normals) < 10:
        return ArcCornerMeasurement(Refusal.ARC_NOT_SEEN, "the seed arc lies outside the corner's quarter (up to right)")
    ideal = seed.centre + seed.radius * normals
    keep = _inside_roi(lens, ideal, config)
    if keep.sum() < 10:
        return ArcCornerMeasurement(Refusal.ARC_NOT_SEEN, "the arc lies outside the region of interest")
    # Step 2a: the recipe's arc among the concentric ones (the seed may be any of them).
    darker = config.opening_polarity == "darker"
    profile = arc_profile(img, lens, seed.centre, seed.radius, normals[keep], opening_darker=darker, feature=config.feature)
    step = profile.feature_step
    if step is None:
        why = f"none of the {len(profile.steps)} steps across the arc is the recipe's feature (arc.feature)"
        return ArcCornerMeasurement(Refusal.ARC_NOT_SEEN, why)
    return measure_circle(img, lens, config, seed.centre, seed.radius - step.offset_px, normals, seed.mid, seed.pixels, darker, rng)


def measure_circle(
    img: NDArray[np.uint8], lens: Lens, config: ArcCornerConfig, centre: F64, radius: float, normals: F64, mid: F64,
    pixels: F64, expect_dark: bool, rng: np.random.Generator,
) -> ArcCornerMeasurement:
    """Steps 2b-4 on the circle about ``centre`` (ideal px) of ``radius``: crossings, robust fit, checks, orientation."""
    s, lim = config.search, config.limits
    search_px = 2.0 * s.downscale + 1.0
    ideal = centre + radius * normals
    keep = _inside_roi(lens, ideal, config)
    if keep.sum() < 10:
        return ArcCornerMeasurement(Refusal.ARC_NOT_SEEN, "the arc lies outside the region of interest")
    found = arc_crossings(
        img, lens, ideal[keep], normals[keep], step_px=1, expect_dark=expect_dark,
        search_px=search_px, level_samples=s.level_samples, max_blur_sigma_px=s.max_blur_sigma_px,
    )
    order = np.argsort(found.order, kind="stable")
    raw_px, contrast = found.raw_px[order], found.contrast[order]
    levels = (found.levels[0][order], found.levels[1][order])
    usable = found.usable[order] & (contrast >= 0.5 * lim.min_contrast_dn)
    flat = background_consistent(levels, usable, s.background_tolerance)
    uneven = int(np.sum(usable & ~flat))
    n_usable = int(usable.sum())
    usable &= flat
    n_prof = len(raw_px)
    checks = [
        at_most("arc saturated share", float(found.saturated.mean()) if n_prof else 0.0, lim.max_saturated_fraction,
                Refusal.SATURATED),
        at_least("arc contrast", float(np.median(contrast[usable])) if usable.any() else 0.0, lim.min_contrast_dn,
                 Refusal.LOW_CONTRAST, " DN"),
        at_most("uneven-background share", uneven / max(n_usable, 1), lim.max_uneven_fraction, Refusal.ARC_MISMATCH),
    ]
    idx = np.flatnonzero(usable)
    # Step 3: the robust circle, in square px (fx on both axes), where the wall's circle is one.
    pts = lens.square_of_raw(raw_px[idx]) if len(idx) else np.zeros((0, 2))
    fitted = robust_circle(
        pts, lens.to_square(centre)[0], radius, search_px=search_px, ransac_band_px=max(s.min_robust_band_px, 0.5),
        robust_k=s.robust_k, min_band_px=s.min_robust_band_px, rng=rng, iterations=s.ransac_iterations,
        radius_tolerance=_COARSE_RADIUS_TOLERANCE,
    ) if len(pts) >= 10 else None
    if fitted is None:
        checks.append(at_least("arc points", 0, lim.min_points, Refusal.ARC_NOT_SEEN))
        return _refused(checks, lens.from_square(pts))
    c, R, inl = _trim_ends(pts, *fitted, s.robust_k, s.min_robust_band_px, mid)
    r = np.hypot(*(pts[inl] - c).T) - R
    ang = np.sort(_angles(pts[inl], c, mid))
    coverage = float(np.degrees(ang[-1] - ang[0]))
    gap = float(np.max(np.diff(ang)) * R) if len(ang) > 1 else float("inf")
    # Profiles within the inliers' stretch of the arc: all of them should be inliers.
    first, last = idx[inl][0], idx[inl][-1]
    share = float(inl.sum()) / float(last - first + 1)
    sigma_c, sigma_r = _covariance(pts[inl], c, R)
    rms = float(np.sqrt(np.mean(r * r)))
    checks += [
        at_least("arc points", int(inl.sum()), lim.min_points, Refusal.ARC_NOT_SEEN),
        at_least("arc coverage", coverage, lim.min_coverage_deg, Refusal.ARC_NOT_SEEN, " deg"),
        at_most("radius deviation", abs(R / config.expected_radius_px - 1.0), lim.radius_tolerance, Refusal.ARC_MISMATCH),
        at_most("arc fit rms", rms, lim.max_rms_px, Refusal.POOR_FIT, " px"),
        at_least("arc inlier share", share, lim.min_inlier_fraction, Refusal.ARC_MISMATCH),
        at_most("arc gap", gap, lim.max_gap_px, Refusal.ARC_MISMATCH, " px"),
        at_most("predicted centre sigma", sigma_c, lim.max_centre_sigma_px, Refusal.UNCERTAIN, " px"),
    ]
    centre = lens.from_square(c)[0]
    orientation = measure_orientation(img, lens, pixels, centre, R, pts[inl], config, search_px, rng)
    failed = next((ch for ch in checks if not ch.passed), None)
    short = failed is not None and all(ch.passed or ch.name in _SHORT_ARC_CHECKS for ch in checks)
    short = short and _runs_out(lens, config, c, R, mid, (float(ang[0]), float(ang[-1])))
    return ArcCornerMeasurement(
        failed.refusal if failed else None,
        f"refused: {failed.describe()}" if failed else "arc corner found",
        centre_px=centre,
        centre_raw_px=lens.distort(centre[None, :])[0],
        radius_px=R,
        centre_sigma_px=sigma_c,
        radius_sigma_px=sigma_r,
        coverage_deg=coverage,
        rms_px=rms,
        orientation=orientation,
        checks=tuple(checks),
        points_ideal=lens.from_square(pts),
        inliers=inl,
        edge_pixels=pixels,
        coarse_corner_px=centre if short else None,
    )


def _refused(checks: list[Check], pts: F64) -> ArcCornerMeasurement:
    failed = next(ch for ch in checks if not ch.passed)
    return ArcCornerMeasurement(failed.refusal, f"refused: {failed.describe()}", checks=tuple(checks), points_ideal=pts)
