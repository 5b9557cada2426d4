"""The rounded corner itself, as a check on the two straight edges.

The arc of the opening's corner is tangent to both straight edges. Its sub-pixel points are
measured like the edges' (profiles along the pixel rows or columns, whichever crosses the arc
more squarely), undistorted, and a circle is fitted to them freely (centre and radius). If both
fitted lines are the true edges, the circle touches both: its centre lies one radius from each
line. A line that is in fact the border of something covering most of an edge, or a shadow,
stands off the arc by as much as it stands off the edge, which is how far it would move the
corner; the "tangency gap" of each line measures that, and the detector refuses above a limit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cellctl.vision.lens import Lens
from cellctl.vision.lines import Line2D
from cellctl.vision.subpixel import measure_crossings

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ArcMeasurement:
    """The corner arc as measured (ideal image px).

    ``gap_top_px``/``gap_right_px``: distance of the fitted circle's centre from each edge line
    minus its radius (0 when the line touches the arc); ``coverage_deg``: the angle the kept
    points span about the centre (the full arc is 90 deg for a square corner).
    """

    centre_px: F64
    radius_px: float
    rms_px: float
    gap_top_px: float
    gap_right_px: float
    coverage_deg: float
    points_raw: F64
    points_ideal: F64
    inliers: NDArray[np.bool_]


def _unit(v: F64) -> F64:
    return v / np.linalg.norm(v)


def estimate_radius(corner: F64, top: Line2D, right: Line2D, pixels: F64, max_radius_px: float) -> float | None:
    """Radius of the circle tangent to both lines that the coarse edge pixels near the corner suggest.

    A pixel q (relative to the corner) on such a circle of radius R satisfies
    |q - k R b| = R, with b the unit bisector into the opening and k = 1 / sin(half the corner
    angle); each pixel gives R by the larger root, and the median is taken.
    """
    b = _unit(top.direction + right.direction)
    half = 0.5 * np.arccos(np.clip(top.direction @ right.direction, -1.0, 1.0))
    k = 1.0 / np.sin(half)
    q = pixels - corner
    # Pixels in the corner region, inside the angle between the two edges, not on the edges.
    a_top = q @ top.direction
    a_right = q @ right.direction
    d_top = np.abs(q @ top.normal)
    d_right = np.abs(q @ right.normal)
    near = (a_top > 2.0) & (a_right > 2.0) & (a_top < max_radius_px) & (a_right < max_radius_px)
    near &= (d_top > 2.0) & (d_right > 2.0)
    q = q[near]
    if len(q) < 10:
        return None
    qb = q @ b
    qq = np.sum(q * q, axis=1)
    a2 = k * k - 1.0
    disc = (k * qb) ** 2 - a2 * qq
    ok = disc >= 0
    if ok.sum() < 10:
        return None
    R = (k * qb[ok] + np.sqrt(disc[ok])) / a2
    R = np.sort(R[(R > 0) & (R < 2 * max_radius_px)])
    if len(R) < 10:
        return None
    # The densest 4 px window, not the median: a seal or a flange draws more arcs beside the
    # feature's (concentric, so their pixels spread over many radii), and marks add pixels too.
    ends = np.searchsorted(R, R + 4.0, side="right")
    i = int(np.argmax(ends - np.arange(len(R))))
    if ends[i] - i < 10:
        return None
    return float(np.median(R[i : ends[i]]))


def fit_circle(points: F64) -> tuple[F64, float]:
    """Geometric least-squares circle (algebraic start, then Gauss-Newton): centre and radius (px)."""
    x, y = points[:, 0], points[:, 1]
    A = np.column_stack([2 * x, 2 * y, np.ones(len(x))])
    sol, *_ = np.linalg.lstsq(A, x * x + y * y, rcond=None)
    c = sol[:2]
    R = float(np.sqrt(max(sol[2] + c @ c, 1e-9)))
    for _ in range(10):
        d = points - c
        dist = np.hypot(d[:, 0], d[:, 1])
        r = dist - R
        J = np.column_stack([-d[:, 0] / dist, -d[:, 1] / dist, -np.ones(len(dist))])
        step, *_ = np.linalg.lstsq(J, -r, rcond=None)
        c = c + step[:2]
        R += float(step[2])
        if np.max(np.abs(step)) < 1e-6:
            break
    return c, R


def ransac_circle(
    points: F64, radius_px: float, band_px: float, iterations: int, rng: np.random.Generator,
    radius_tolerance: float = 0.2,
) -> NDArray[np.bool_]:
    """Inliers of the circle through three of the points that most points lie within ``band_px`` of.

    Only circles within ``radius_tolerance`` (a fraction) of the expected radius count: a straight
    stretch (a mark's border) is a circle too, of a huge radius.
    """
    n = len(points)
    idx = rng.integers(0, n, size=(iterations, 3))
    a, b, c = points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]
    # Circumcentre of each triplet (perpendicular bisectors); collinear triplets are skipped.
    d = 2.0 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1]) + c[:, 0] * (a[:, 1] - b[:, 1]))
    ok = np.abs(d) > 1e-9
    a, b, c, d = a[ok], b[ok], c[ok], d[ok]
    if len(d) == 0:
        return np.ones(n, dtype=bool)
    sa, sb, sc = np.sum(a * a, axis=1), np.sum(b * b, axis=1), np.sum(c * c, axis=1)
    ux = (sa * (b[:, 1] - c[:, 1]) + sb * (c[:, 1] - a[:, 1]) + sc * (a[:, 1] - b[:, 1])) / d
    uy = (sa * (c[:, 0] - b[:, 0]) + sb * (a[:, 0] - c[:, 0]) + sc * (b[:, 0] - a[:, 0])) / d
    radius = np.hypot(a[:, 0] - ux, a[:, 1] - uy)
    plausible = np.abs(radius - radius_px) <= radius_tolerance * radius_px
    if not np.any(plausible):
        return np.zeros(n, dtype=bool)
    ux, uy, radius = ux[plausible], uy[plausible], radius[plausible]
    dist = np.hypot(points[:, None, 0] - ux[None, :], points[:, None, 1] - uy[None, :]) - radius[None, :]
    inside = np.abs(dist) < band_px
    return inside[:, int(np.argmax(inside.sum(axis=0)))]


def measure_arc(
    image: NDArray[np.uint8],
    lens: Lens,
    corner: F64,
    top: Line2D,
    right: Line2D,
    radius_px: float,
    *,
    expect_dark: bool,
    min_contrast_dn: float,
    search_px: float,
    level_samples: int,
    max_blur_sigma_px: float,
    robust_k: float,
    min_band_px: float,
) -> ArcMeasurement | None:
    """Sub-pixel points on the arc predicted from the two lines and ``radius_px``, and the circle through them.

    ``top``/``right`` point away from the corner. Returns None when fewer than 10 points are found.
    """
    b = _unit(top.direction + right.direction)
    half = 0.5 * np.arccos(np.clip(top.direction @ right.direction, -1.0, 1.0))
    centre = corner + radius_px / np.sin(half) * b
    e1 = _unit(corner + (centre - corner) @ top.direction * top.direction - centre)  # to the top tangent point
    e2 = _unit(corner + (centre - corner) @ right.direction * right.direction - centre)
    span = float(np.arccos(np.clip(e1 @ e2, -1.0, 1.0)))
    e_perp = _unit(e2 - (e1 @ e2) * e1)
    t = np.linspace(0.0, span, max(int(span * radius_px), 8))
    normals = np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e_perp
    ideal = centre + radius_px * normals
    inside = np.all((ideal > -50) & (ideal < np.array([lens.width_px, lens.height_px]) + 50), axis=1)
    ideal, normals = ideal[inside], normals[inside]
    if len(ideal) < 10:
        return None
    found = arc_crossings(
        image, lens, ideal, normals, step_px=2, expect_dark=expect_dark, search_px=search_px,
        level_samples=level_samples, max_blur_sigma_px=max_blur_sigma_px,
    )
    keep = found.usable & (found.contrast >= 0.5 * min_contrast_dn)
    pts_raw = found.raw_px[keep]
    if len(pts_raw) < 10:
        return None
    pts = lens.undistort(pts_raw)
    fitted = robust_circle(
        pts, centre, radius_px, search_px=search_px, ransac_band_px=max(min_band_px, 0.5), robust_k=robust_k,
        min_band_px=min_band_px, rng=np.random.default_rng(0),
    )
    if fitted is None:
        return None
    c, R, inl = fitted
    r = np.hypot(*(pts[inl] - c).T) - R
    d = pts[inl] - c
    mid = _unit(e1 + e2)
    ang = np.arctan2(mid[0] * d[:, 1] - mid[1] * d[:, 0], d @ mid)  # about the arc's middle
    coverage = float(np.degrees(ang.max() - ang.min()))
    gap_top = abs(float(top.signed_distance(c[None])[0])) - R
    gap_right = abs(float(right.signed_distance(c[None])[0])) - R
    return ArcMeasurement(c, float(R), float(np.sqrt(np.mean(r * r))), gap_top, gap_right, coverage, pts_raw, pts, inl)


@dataclass(frozen=True)
class ArcCrossings:
    """Edge crossings on the pixel rows or columns crossing an arc (raw px), in the arc's order per group.

    ``contrast`` is signed so that the expected polarity is positive; ``usable``: a valid crossing,
    not saturated, blur within the limit; ``levels``: the two plateau levels of each profile;
    ``order``: the position along the arc (the index of the nearest sample of the arc given).
    """

    raw_px: F64
    contrast: F64
    usable: NDArray[np.bool_]
    saturated: NDArray[np.bool_]
    levels: tuple[F64, F64]
    order: F64


def arc_crossings(
    image: NDArray[np.uint8],
    lens: Lens,
    ideal: F64,
    normals: F64,
    *,
    step_px: int,
    expect_dark: bool,
    search_px: float,
    level_samples: int,
    max_blur_sigma_px: float,
) -> ArcCrossings:
    """Sub-pixel crossings of the edge predicted at ``ideal`` (ideal px, outward unit ``normals``).

    Each profile runs along the pixel column or row closest to the normal (every ``step_px``-th),
    the same polarity as the top edge (scanning down) or the right edge (scanning right).
    """
    raw = lens.distort(ideal)
    raw_pts, contrasts, valid, sat, lo, hi, order = [], [], [], [], [], [], []
    for along_v in (True, False):
        group = np.abs(normals[:, 1]) >= np.abs(normals[:, 0]) if along_v else np.abs(normals[:, 1]) < np.abs(normals[:, 0])
        if group.sum() < 2:
            continue
        step_axis = 0 if along_v else 1  # the coordinate that steps from profile to profile
        s = raw[group, step_axis]
        e = raw[group, 1 - step_axis]
        k = np.flatnonzero(group).astype(float)
        srt = np.argsort(s)
        s, e, k = s[srt], e[srt], k[srt]
        fixed = np.arange(int(np.ceil(s[0])), int(np.floor(s[-1])) + 1, step_px, dtype=np.int64)
        if len(fixed) == 0:
            continue
        expected = np.interp(fixed.astype(float), s, e)
        inside_img = (fixed >= 0) & (fixed < (lens.width_px if along_v else lens.height_px))
        fixed, expected = fixed[inside_img], expected[inside_img]
        if len(fixed) == 0:
            continue
        cr = measure_crossings(
            image, fixed, expected, along_rows=not along_v, search_px=search_px,
            level_samples=level_samples, max_blur_sigma_px=max_blur_sigma_px,
        )
        sign = (-1.0 if along_v else 1.0) * (1.0 if expect_dark else -1.0)
        pts = np.column_stack([fixed.astype(float), cr.position]) if along_v else np.column_stack([cr.position, fixed.astype(float)])
        raw_pts.append(pts)
        contrasts.append(sign * cr.contrast)
        valid.append(cr.valid & ~cr.saturated & (cr.blur_sigma_px <= max_blur_sigma_px))
        sat.append(cr.saturated)
        lo.append(cr.level_before)
        hi.append(cr.level_after)
        order.append(np.interp(fixed.astype(float), s, k))
    if not raw_pts:
        z = np.zeros(0)
        return ArcCrossings(np.zeros((0, 2)), z, np.zeros(0, bool), np.zeros(0, bool), (z, z), z)
    return ArcCrossings(
        np.vstack(raw_pts), np.concatenate(contrasts), np.concatenate(valid), np.concatenate(sat),
        (np.concatenate(lo), np.concatenate(hi)), np.concatenate(order),
    )


def robust_circle(
    pts: F64,
    centre: F64,
    radius_px: float,
    *,
    search_px: float,
    ransac_band_px: float,
    robust_k: float,
    min_band_px: float,
    rng: np.random.Generator,
    iterations: int = 100,
    radius_tolerance: float = 0.2,
) -> tuple[F64, float, NDArray[np.bool_]] | None:
    """Circle through ``pts`` (ideal px) near the predicted one: RANSAC, then least squares within a robust band (3 times).

    Returns (centre, radius, inlier mask), or None when fewer than 10 points remain.
    """
    # Start from the points near the predicted arc: a mark or a spot crossing the arc gives
    # crossings far off it, which a first unweighted circle would follow.
    near = np.abs(np.hypot(*(pts - centre).T) - radius_px) < search_px
    if near.sum() < 10:
        return None
    # Then the circle most of them agree on (RANSAC), so that a stretch of points displaced by a
    # mark along the arc cannot pull the first fit (and with it the robust band) off.
    inl = near.copy()
    inl[near] = ransac_circle(pts[near], radius_px, ransac_band_px, iterations, rng, radius_tolerance)
    if inl.sum() < 10:
        return None
    c, R = fit_circle(pts[inl])
    for _ in range(3):
        r = np.hypot(*(pts - c).T) - R
        ri = r[inl]
        sigma = 1.4826 * float(np.median(np.abs(ri - np.median(ri))))
        new = np.abs(r) < max(robust_k * sigma, min_band_px)
        if new.sum() < 10:
            break
        inl = new
        c, R = fit_circle(pts[inl])
    return c, float(R), inl
