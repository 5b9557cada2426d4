"""Coarse search for the two straight edges beside the corner: Canny, then probabilistic Hough.

Runs on the region of interest shrunk by an integer factor (area averaging), which keeps long
straight edges intact and the cost low; its only job is to seed the sub-pixel stage within a few
pixels. Segments leaning less than ``max_tilt_deg`` from the image rows are candidates for the
top edge, from the columns for the right edge; collinear segments are grouped into lines, and
the pair of lines that best forms the opening's upper-right corner (the top edge to the left of
the corner, the right edge below it, the opening on the expected side of both) is chosen.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.config.vision import CoarseConfig, RoiConfig
from cellctl.vision.lens import Lens
from cellctl.vision.lines import Line2D, fit_line, intersect

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class LineCluster:
    """Collinear Hough segments (full-resolution raw pixels) and the line through them."""

    segments: F64  # (K, 4): u0, v0, u1, v1
    line: Line2D

    @property
    def length_px(self) -> float:
        d = self.segments[:, 2:] - self.segments[:, :2]
        return float(np.sum(np.hypot(d[:, 0], d[:, 1])))


@dataclass(frozen=True)
class CoarseCorner:
    """The coarse result: the chosen lines, their Canny edge pixels and the provisional corner.

    All coordinates are full-resolution raw image pixels. ``opening_darker`` is what the image
    shows (the opening side of both edges darker than the wall side).
    """

    top: LineCluster
    right: LineCluster
    corner_px: F64
    top_points: F64
    right_points: F64
    opening_darker: bool
    segments: F64  # every Hough segment found, (K, 4)
    edge_pixels: F64  # every Canny pixel, (N, 2)


@dataclass(frozen=True)
class CoarseFailure:
    """Why no corner was found, for the refusal message."""

    missing: str  # "corner" or the edge's name ("top", "right")
    message: str
    segments: F64


# The frame's levels when no edge was found: the brightest 1 % this dark, or the darkest 1 % this
# bright, leave no room for an edge of the contrast the detector needs (LimitsConfig.min_contrast_dn).
DARK_P99_DN = 20.0
BRIGHT_P1_DN = 250.0
DARK_HINT = "check the lighting, the lens cap and the camera's exposure (devices.camera.exposure_us)"
BRIGHT_HINT = "shorten the camera's exposure (devices.camera.exposure_us) or check the lighting for glare"


def level_problem(crop: NDArray[np.uint8]) -> str:
    """Why a region without a straight edge shows none: too dark, saturated, or its levels (for the message)."""
    mean = float(np.mean(crop))
    p1, p99 = (float(v) for v in np.percentile(crop, [1.0, 99.0]))
    levels = f"mean {mean:.0f} DN, 1st-99th percentile {p1:.0f}-{p99:.0f} DN"
    if p99 < DARK_P99_DN:
        return f"the frame is too dark ({levels}): {DARK_HINT}"
    if p1 >= BRIGHT_P1_DN:
        return f"the frame is saturated, too bright ({levels}): {BRIGHT_HINT}"
    return f"no straight edge found in the region of interest ({levels})"


_ARC_STEP_DEG = 2.0  # segments of one straight edge differ by the Hough's angle step (0.5 deg); an arc's turn by more
_ARC_CENTRE_DEG = 10.0  # a chord's end off its arc by the shrunk image's few px turns its bisector by a few deg
_ARC_BAND_SHRUNK_PX = 6.0  # a Hough line follows an arc ~2 shrunk px each side of the dilated Canny line: twice that, more


def _on_arcs(segs: F64, band_px: float) -> tuple[float, float] | None:
    """The radii (px, least and most) of the concentric arcs the segments (K, 4) lie on as chords, or None.

    A curved edge gives Hough segments as short chords, each square to the radius through its middle: their
    perpendicular bisectors meet in the arcs' centre (the wall's, flange's and seal's arcs share it), their
    directions turning along the arc (three directions at least), and each bulging from its arc by its sagitta
    L^2 / 8r, at most ``band_px`` (the Hough's band, px). A straight edge's segments do not turn, a turned corner's two
    edges give two directions and chords too long for any arc through the centre; scattered marks miss the centre.
    """
    if len(segs) < 3:
        return None
    d = segs[:, 2:] - segs[:, :2]
    half = np.hypot(d[:, 0], d[:, 1]) / 2.0
    u = d / (2.0 * half[:, None])
    turn = np.sort((np.degrees(np.arctan2(u[:, 1], u[:, 0])) + 90.0) % 180.0 - 90.0)
    if np.count_nonzero(np.diff(turn) > _ARC_STEP_DEG) < 2:  # one or two directions: straight edges (a turned corner)
        return None
    mid = (segs[:, :2] + segs[:, 2:]) / 2.0
    A = np.einsum("ki,kj->ij", u, u)
    if np.linalg.cond(A) > 1e6:
        return None
    c = np.linalg.solve(A, np.einsum("ki,kj,kj->i", u, u, mid))  # least squares: (c - mid_k) . u_k = 0 for all k
    radial = mid - c
    dist = np.hypot(radial[:, 0], radial[:, 1])
    if np.max(np.abs(np.sum(radial * u, axis=1)) / np.maximum(dist, 1e-9)) > np.sin(np.radians(_ARC_CENTRE_DEG)):
        return None
    r = np.sqrt(dist**2 + half**2)  # a chord's middle lies inside its circle
    if np.max(r - dist) > band_px:
        return None
    return float(r.min()), float(r.max())


def _tilt_note(ang: F64, segs: F64, cfg: CoarseConfig, missing: str) -> str:
    """Why no edge along the rows (top) or columns (right) was kept, when segments leaning past the limit were dropped."""
    lean = np.abs(ang) if missing == "top" else 90.0 - np.abs(ang)  # from the rows, or from the columns
    leaning = lean[(lean > cfg.max_tilt_deg) & (lean < 45.0)]
    if len(leaning) == 0:
        return ""
    said = (
        f"; {len(leaning)} straight segment(s) lean {leaning.min():.1f}-{leaning.max():.1f} deg from the image "
        f"{'rows' if missing == 'top' else 'columns'}, past vision.coarse.max_tilt_deg ({cfg.max_tilt_deg:g} deg)"
    )
    curved = (np.abs(ang) > cfg.max_tilt_deg) & (np.abs(ang) < 90.0 - cfg.max_tilt_deg)
    radii = _on_arcs(segs[curved], _ARC_BAND_SHRUNK_PX * cfg.downscale)
    if radii is None:
        return said + ": check the car body's posture or raise the limit"
    return (
        f"{said}, and lie on arcs about one centre (radius {radii[0]:.0f}-{radii[1]:.0f} px): the opening's rounded "
        f"corner, with too little straight {missing} edge beside its arc in the region of interest; check "
        "layout.opening.corner_radius_mm (a recipe's in its [process.recipes.opening]) against the opening (a large "
        "radius leaves the corner method little straight edge in view), the car body's posture and placement (where "
        "they put the corner) and vision.roi"
    )


def _to_full(pts_small: F64, k: int, roi: RoiConfig) -> F64:
    """Map shrunk-image pixel centres to full-resolution raw pixel coordinates."""
    return (pts_small + 0.5) * k - 0.5 + np.array([roi.x_px, roi.y_px], dtype=float)


def _segment_lines(segs: F64) -> list[Line2D]:
    out = []
    for u0, v0, u1, v1 in segs:
        d = np.array([u1 - u0, v1 - v0])
        out.append(Line2D(np.array([(u0 + u1) / 2, (v0 + v1) / 2]), d / np.linalg.norm(d)))
    return out


def _cluster(segs: F64, tol_px: float) -> list[LineCluster]:
    """Group segments (longest first) whose two ends lie within ``tol_px`` of a group's line."""
    if len(segs) == 0:
        return []
    lengths = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
    order = np.argsort(-lengths)
    groups: list[list[int]] = []
    lines: list[Line2D] = []
    for idx in order:
        ends = segs[idx].reshape(2, 2)
        placed = False
        for g, line in enumerate(lines):
            if np.all(np.abs(line.signed_distance(ends)) < tol_px):
                groups[g].append(int(idx))
                pts = segs[groups[g]].reshape(-1, 2)
                lines[g] = fit_line(pts).line
                placed = True
                break
        if not placed:
            groups.append([int(idx)])
            lines.append(_segment_lines(segs[[idx]])[0])
    return [LineCluster(segs[g], line) for g, line in zip(groups, lines)]


def _side_mean(small: NDArray[np.uint8], cluster: LineCluster, offset_px: float, k: int, roi: RoiConfig) -> float:
    """Mean grey level of the shrunk image ``offset_px`` (full-res) off the line's segments, on its normal side."""
    pts = []
    for u0, v0, u1, v1 in cluster.segments:
        n = max(int(np.hypot(u1 - u0, v1 - v0) / (4 * k)), 2)
        t = np.linspace(0.1, 0.9, n)
        pts.append(np.column_stack([u0 + t * (u1 - u0), v0 + t * (v1 - v0)]))
    P = np.vstack(pts) + offset_px * cluster.line.normal
    small_xy = (P - np.array([roi.x_px, roi.y_px])) / k + 0.5 / k - 0.5
    ix = np.clip(np.rint(small_xy[:, 0]).astype(int), 0, small.shape[1] - 1)
    iy = np.clip(np.rint(small_xy[:, 1]).astype(int), 0, small.shape[0] - 1)
    return float(np.mean(small[iy, ix]))


def _ideal_direction(cluster: LineCluster, lens: Lens | None) -> F64:
    """The cluster's unit direction in the ideal image (undistorted, square pixels); the raw line's without a lens."""
    if lens is None:
        return np.asarray(cluster.line.direction, dtype=float)
    try:
        ends = lens.square_of_raw(cluster.segments.reshape(-1, 2))
    except ValueError:  # a lens that folds over there: the raw direction, as without one
        return np.asarray(cluster.line.direction, dtype=float)
    centred = ends - ends.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return np.asarray(vt[0], dtype=float)


def find_coarse_corner(
    image: NDArray[np.uint8], roi: RoiConfig, cfg: CoarseConfig, opening_polarity: str, lens: Lens | None = None
) -> CoarseCorner | CoarseFailure:
    """Canny + probabilistic Hough on the shrunk ROI; the two lines of the upper-right corner.

    With ``lens`` the right angle is judged in the ideal image: near the border distortion turns a
    raw edge (about 0.1 deg for the twin's lens, degrees for a wide-angle one).
    """
    k = int(cfg.downscale)
    crop = image[roi.y_px : roi.y_px + roi.height_px, roi.x_px : roi.x_px + roi.width_px]
    if k > 1:
        small = cv2.resize(crop, (crop.shape[1] // k, crop.shape[0] // k), interpolation=cv2.INTER_AREA)
    else:
        small = crop
    if cfg.blur_sigma_px > 0:
        small_blur = cv2.GaussianBlur(small, (0, 0), cfg.blur_sigma_px)
    else:
        small_blur = small
    edges = cv2.Canny(small_blur, cfg.canny_low, cfg.canny_high, L2gradient=cfg.canny_l2_gradient)
    # The Hough walk follows the ideal digital line pixel by pixel; a one-pixel-thin Canny
    # staircase of a slightly tilted edge leaves it gaps, so the walk runs on a 3 x 3 dilation.
    thick = cv2.dilate(edges, np.ones((3, 3), np.uint8))
    found = cv2.HoughLinesP(
        thick,
        cfg.hough_rho_px,
        np.deg2rad(cfg.hough_theta_deg),
        cfg.hough_threshold,
        minLineLength=cfg.hough_min_length_px / k,
        maxLineGap=cfg.hough_max_gap_px / k,
    )
    if found is None:
        return CoarseFailure("corner", level_problem(crop), np.zeros((0, 4)))
    segs_small = found.reshape(-1, 4).astype(float)
    segs = np.hstack([_to_full(segs_small[:, :2], k, roi), _to_full(segs_small[:, 2:], k, roi)])
    ang = np.degrees(np.arctan2(segs[:, 3] - segs[:, 1], segs[:, 2] - segs[:, 0]))
    ang = (ang + 90.0) % 180.0 - 90.0  # (-90, 90]
    horizontal = np.abs(ang) <= cfg.max_tilt_deg
    vertical = np.abs(ang) >= 90.0 - cfg.max_tilt_deg
    tol = cfg.cluster_tolerance_px
    tops = _cluster(segs[horizontal], tol)
    rights = _cluster(segs[vertical], tol)
    if not tops or not rights:
        missing = "top" if not tops else "right"
        what = "running along the image rows" if missing == "top" else "running along the image columns"
        message = f"no {missing} edge found: no straight edge {what} in the region of interest"
        return CoarseFailure(missing, message + _tilt_note(ang, segs, cfg, missing), segs)

    x0, y0 = roi.x_px, roi.y_px
    x1, y1 = roi.x_px + roi.width_px - 1, roi.y_px + roi.height_px - 1
    # Which side of each line is darker: the opening is below the top edge and left of the right.
    top_dark = []
    for top in tops:
        oriented = LineCluster(top.segments, top.line.oriented([1.0, 0.0]))  # normal points down (+v)
        top_dark.append(_side_mean(small, oriented, 3.0 * k, k, roi) < _side_mean(small, oriented, -3.0 * k, k, roi))
    right_dark = []
    for right in rights:
        oriented = LineCluster(right.segments, right.line.oriented([0.0, 1.0]))  # normal points left (-u)
        right_dark.append(_side_mean(small, oriented, 3.0 * k, k, roi) < _side_mean(small, oriented, -3.0 * k, k, roi))
    top_dirs = [_ideal_direction(t, lens) for t in tops]
    right_dirs = [_ideal_direction(r, lens) for r in rights]
    best: tuple[float, LineCluster, LineCluster, F64, bool] | None = None
    reasons: list[str] = []
    for top, t_dark, t_dir in zip(tops, top_dark, top_dirs):
        for right, r_dark, r_dir in zip(rights, right_dark, right_dirs):
            c = intersect(top.line, right.line)
            if c is None or not (x0 <= c[0] <= x1 and y0 <= c[1] <= y1):
                reasons.append("lines meet outside the region of interest")
                continue
            skew = abs(90.0 - float(np.degrees(np.arccos(np.clip(abs(t_dir @ r_dir), 0.0, 1.0)))))
            if skew > cfg.max_corner_skew_deg:
                reasons.append(f"no pair of lines meets within {cfg.max_corner_skew_deg:g} deg of a right angle")
                continue
            # The top edge lies left of the corner, the right edge below it.
            mid_top = (top.segments[:, 0] + top.segments[:, 2]) / 2
            mid_right = (right.segments[:, 1] + right.segments[:, 3]) / 2
            lt = np.hypot(top.segments[:, 2] - top.segments[:, 0], top.segments[:, 3] - top.segments[:, 1])
            lr = np.hypot(right.segments[:, 2] - right.segments[:, 0], right.segments[:, 3] - right.segments[:, 1])
            support_top = float(np.sum(lt[mid_top < c[0]]))
            support_right = float(np.sum(lr[mid_right > c[1]]))
            if support_top <= 0 or support_right <= 0:
                reasons.append("no pair of lines forms an upper-right corner")
                continue
            if t_dark != r_dark:
                reasons.append("the two edges disagree on which side is the opening")
                continue
            if opening_polarity == "darker" and not t_dark:
                reasons.append("the opening side is brighter than the wall, the recipe expects it darker")
                continue
            if opening_polarity == "brighter" and t_dark:
                reasons.append("the opening side is darker than the wall, the recipe expects it brighter")
                continue
            score = min(support_top, support_right)
            if best is None or score > best[0]:
                best = (score, top, right, c, t_dark)
    if best is None:
        why = max(set(reasons), key=reasons.count) if reasons else "no candidate lines"
        return CoarseFailure("corner", f"corner not found: {why}", segs)
    _, top, right, c, dark = best

    # Canny pixels near each chosen line, on its side of the corner.
    nz = cv2.findNonZero(edges)
    pts = _to_full(nz.reshape(-1, 2).astype(float), k, roi) if nz is not None else np.zeros((0, 2))
    band = max(tol, 1.5 * k)
    near_top = (np.abs(top.line.signed_distance(pts)) < band) & (pts[:, 0] < c[0] - 2 * k)
    near_right = (np.abs(right.line.signed_distance(pts)) < band) & (pts[:, 1] > c[1] + 2 * k)
    return CoarseCorner(top, right, c, pts[near_top], pts[near_right], dark, segs, pts)
