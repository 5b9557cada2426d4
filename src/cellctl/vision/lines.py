"""Straight lines in the image: total least squares, RANSAC, intersection (paper section 4.2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Line2D:
    """A line through ``point`` along the unit vector ``direction`` (pixel coordinates)."""

    point: F64
    direction: F64

    @property
    def normal(self) -> F64:
        """Unit normal: the direction turned by +90 deg (from u towards v)."""
        return np.array([-self.direction[1], self.direction[0]])

    def signed_distance(self, points: ArrayLike) -> F64:
        """Distance of points (N, 2) from the line, positive on the ``normal`` side."""
        P = np.asarray(points, dtype=float)
        return (P - self.point) @ self.normal

    def along(self, points: ArrayLike) -> F64:
        """Position of points (N, 2) along the line from ``point`` (px, in ``direction``)."""
        P = np.asarray(points, dtype=float)
        return (P - self.point) @ self.direction

    def at(self, t: ArrayLike) -> F64:
        """Points (N, 2) at positions ``t`` along the line."""
        return self.point + np.asarray(t, dtype=float)[:, None] * self.direction

    def oriented(self, towards: ArrayLike) -> "Line2D":
        """The same line with its direction turned to have a positive component along ``towards``."""
        if float(self.direction @ np.asarray(towards, dtype=float)) < 0.0:
            return Line2D(self.point, -self.direction)
        return self


@dataclass(frozen=True)
class LineFit:
    """A least-squares line and how well its points fit it."""

    line: Line2D
    rms_px: float
    n_points: int
    sigma_offset_px: float  # 1-sigma of the line's offset at ``line.point`` (the centroid)
    sigma_angle_rad: float  # 1-sigma of its direction
    spread_px: float  # RMS extent of the points along the line about the centroid


def fit_line(points: ArrayLike) -> LineFit:
    """Total least squares line through points (N >= 2): centroid and principal direction.

    Returns the fit with its residual RMS and the first-order uncertainty of offset and angle
    (residual RMS / sqrt(N) and residual RMS / (spread * sqrt(N))).
    """
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 2 or P.shape[0] < 2:
        raise ValueError(f"fit_line needs at least 2 points of shape (N, 2), got {P.shape}")
    c = P.mean(axis=0)
    Q = P - c
    cov = Q.T @ Q
    evals, evecs = np.linalg.eigh(cov)
    d = evecs[:, 1]
    n = len(P)
    resid = Q @ np.array([-d[1], d[0]])
    rms = float(np.sqrt(np.mean(resid**2)))
    spread = float(np.sqrt(max(evals[1], 0.0) / n))
    dof = max(n - 2, 1)
    sigma = float(np.sqrt(np.sum(resid**2) / dof))
    sig_off = sigma / np.sqrt(n)
    sig_ang = sigma / (spread * np.sqrt(n)) if spread > 0 else float("inf")
    return LineFit(Line2D(c, d), rms, n, float(sig_off), float(sig_ang), spread)


def ransac_line(points: ArrayLike, band_px: float, iterations: int, rng: np.random.Generator) -> NDArray[np.bool_]:
    """Inlier mask of the two-point line hypothesis with the most points within ``band_px``.

    Ties go to the hypothesis with the smaller sum of squared in-band residuals. The random
    stream ``rng`` makes the result reproducible.
    """
    P = np.asarray(points, dtype=float)
    n = len(P)
    if n < 2:
        return np.zeros(n, dtype=bool)
    i = rng.integers(0, n, size=iterations)
    j = rng.integers(0, n, size=iterations)
    keep = i != j
    i, j = i[keep], j[keep]
    d = P[j] - P[i]
    length = np.hypot(d[:, 0], d[:, 1])
    ok = length > 1e-9
    i, j, d, length = i[ok], j[ok], d[ok], length[ok]
    if len(i) == 0:
        return np.zeros(n, dtype=bool)
    normals = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    best_mask = np.zeros(n, dtype=bool)
    best_score = (-1, 0.0)
    # Chunks keep the (hypotheses x points) residual matrix small.
    chunk = max(1, 2_000_000 // max(n, 1))
    for s in range(0, len(i), chunk):
        nn = normals[s : s + chunk]
        p0 = P[i[s : s + chunk]]
        r = P @ nn.T - np.sum(p0 * nn, axis=1)[None, :]
        inb = np.abs(r) < band_px
        counts = inb.sum(axis=0)
        cost = np.where(inb, r * r, 0.0).sum(axis=0)
        k = int(np.lexsort((cost, -counts))[0])
        if (counts[k], -cost[k]) > (best_score[0], -best_score[1]):
            best_score = (int(counts[k]), float(cost[k]))
            best_mask = inb[:, k].copy()
    return best_mask


def intersect(a: Line2D, b: Line2D) -> F64 | None:
    """The intersection point of two lines, or None if they are (nearly) parallel."""
    M = np.column_stack([a.direction, -b.direction])
    det = float(np.linalg.det(M))
    if abs(det) < 1e-9:
        return None
    t = np.linalg.solve(M, b.point - a.point)
    return a.point + t[0] * a.direction


def line_angle_to_u(direction: ArrayLike) -> float:
    """Angle (rad) of a line's direction to the image u axis, in (-pi/2, pi/2]: atan2(dv, du), du >= 0."""
    d = np.asarray(direction, dtype=float)
    if d[0] < 0.0 or (d[0] == 0.0 and d[1] < 0.0):
        d = -d
    return float(np.arctan2(d[1], d[0]))
