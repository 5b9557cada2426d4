"""Flush on the move: the step between glass and wall where one continuous leg of the sweep crosses an edge.

A sweep's leg carries the robot's error of that move: the ends' errors blended along the path,
the deflection at speed, the accuracy field along the way. Readings on the glass and on the wall
taken on *one* leg, a few centimetres either side of the edge, carry nearly the same error, so
their difference is the flush; read on separate legs they carry the two legs' independent errors.

Per crossing leg, each side's heights (z in T, mm) are fitted with a line in the position ``s``
along the leg, in windows mirrored about the leg's middle (which lies in the gap), and both are
taken to that middle: an error linear along the leg cancels exactly, one even about the middle (the
deflection of a short leg's speed profile, the curvature of the accuracy field) cancels too. The steps at three or
more crossings then give the glass's plane against the wall's as in :mod:`cellctl.inspection.flush`:
``step = dZ - dRy x + dRx y`` at the crossing point (x, y).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.inspection.flush import FlushError, FlushResult

MIN_SIDE_READINGS = 4  # per side of a crossing: a line and its scatter
MIN_STEP_SIGMA_MM = 0.001  # a crossing's weight is capped here: its lines' scatter does not see every error


@dataclass(frozen=True)
class EdgeCrossing:
    """The step at one leg's crossing of an edge, in the measured workpiece frame T.

    Attributes:
        x_mm, y_mm: the crossing point (the leg's middle, in the gap).
        step_mm: the glass's height over the wall's there (+ = into the wall, as dZ).
        sigma_mm: the step's 1-sigma from the two lines' residuals.
        glass_readings, wall_readings: readings fitted on each side (mirrored windows).
        glass_rms_mm, wall_rms_mm: the two lines' residuals.
    """

    x_mm: float
    y_mm: float
    step_mm: float
    sigma_mm: float
    glass_readings: int
    wall_readings: int
    glass_rms_mm: float
    wall_rms_mm: float


def surface_at(xy: ArrayLike, gap_mm: float, margin_mm: float) -> NDArray[np.int_]:
    """(N,) +1 where a point (x, y in T, mm) lies on the glass (inside its edge), -1 on the wall (outside the
    opening's top or right edge), 0 in the gap or within ``margin_mm`` of an edge."""
    p = np.atleast_2d(np.asarray(xy, dtype=float))
    x, y = p[:, 0], p[:, 1]
    glass = (x < -(gap_mm + margin_mm)) & (y > gap_mm + margin_mm)
    wall = (x > margin_mm) | (y < -margin_mm)
    return glass.astype(int) - wall.astype(int)


def crossing_legs(path_mm: Sequence[ArrayLike], gap_mm: float, margin_mm: float) -> list[tuple[int, NDArray[np.float64], NDArray[np.float64]]]:
    """The legs of a sweep path (corners in T, mm) that run from one surface to the other: (j, start, end), leg j
    being corners j -> j + 1."""
    corners = np.asarray(path_mm, dtype=float)
    surface = surface_at(corners, gap_mm, margin_mm)
    return [(j, corners[j], corners[j + 1]) for j in range(len(corners) - 1) if surface[j] * surface[j + 1] < 0]


def _line_at_zero(s: NDArray[np.float64], z: NDArray[np.float64]) -> tuple[float, float, float]:
    """Least-squares ``z = a + b s``: a, its 1-sigma from the residual, and the RMS residual."""
    A = np.column_stack([np.ones(len(s)), s])
    coef, *_ = np.linalg.lstsq(A, z, rcond=None)
    residual = z - A @ coef
    rms = float(np.sqrt(np.sum(residual**2) / max(len(s) - 2, 1)))
    cov = np.linalg.inv(A.T @ A)
    return float(coef[0]), rms * float(np.sqrt(cov[0, 0])), rms


def step_across_edge(
    points_T: ArrayLike, on_glass: ArrayLike, start_xy: ArrayLike, end_xy: ArrayLike, *, max_rms_mm: float
) -> EdgeCrossing:
    """The flush step where the leg from ``start_xy`` to ``end_xy`` (mm in T) crosses from one surface to the other.

    ``points_T`` (N, 3) are the leg's readings in T, ``on_glass`` (N,) True for the glass's and False
    for the wall's (readings in the gap already left out). Raises FlushError when a side has too few
    readings, the sides overlap along the leg (it crosses more than one edge), or a line's residual
    exceeds ``max_rms_mm``.
    """
    p = np.asarray(points_T, dtype=float)
    glass = np.asarray(on_glass, dtype=bool)
    a, b = np.asarray(start_xy, dtype=float), np.asarray(end_xy, dtype=float)
    length = float(np.linalg.norm(b - a))
    if length == 0.0:
        raise FlushError("a crossing leg has no length; its start and end are the same point")
    u = (b - a) / length
    s = (p[:, :2] - a) @ u
    sides = {True: s[glass], False: s[~glass]}
    for side, what in ((True, "glass"), (False, "wall")):
        if len(sides[side]) < MIN_SIDE_READINGS:
            raise FlushError(
                f"{len(sides[side])} {what} readings on the leg from {a.tolist()} to {b.tolist()} mm "
                f"(at least {MIN_SIDE_READINGS}): does the leg cross the edge with room on both sides?"
            )
    first = sides[True] if np.median(sides[True]) < np.median(sides[False]) else sides[False]
    second = sides[False] if first is sides[True] else sides[True]
    if first.max() >= second.min():
        raise FlushError(
            f"glass and wall readings alternate along the leg from {a.tolist()} to {b.tolist()} mm: "
            "it crosses more than one edge; let each crossing leg cross one straight edge once"
        )
    s_c = 0.5 * length  # a leg's speed profile is even about its middle, and so is the deflection it causes
    if not first.max() < s_c < second.min():
        raise FlushError(
            f"the leg from {a.tolist()} to {b.tolist()} mm does not cross the gap at its middle "
            "(its readings on one surface pass it): centre each crossing leg on the gap"
        )
    reach = min(s_c - first.min(), second.max() - s_c)  # mirrored windows: what is even about s_c cancels
    fits: dict[bool, tuple[float, float, float, int]] = {}
    for side, what in ((True, "glass"), (False, "wall")):
        keep = (glass == side) & (np.abs(s - s_c) <= reach + 1e-9)
        if np.count_nonzero(keep) < MIN_SIDE_READINGS:
            raise FlushError(f"the {what} side of the crossing at s = {s_c:.1f} mm keeps too few readings in its mirrored window")
        at, sigma, rms = _line_at_zero(s[keep] - s_c, p[keep, 2])
        if rms > max_rms_mm:
            raise FlushError(
                f"the {what} readings beside the crossing at {(a + s_c * u).round(1).tolist()} mm scatter by {rms:.3f} mm "
                f"(> {max_rms_mm:g} mm): a reading off another surface; check the sweep's legs against the opening"
            )
        fits[side] = (at, sigma, rms, int(np.count_nonzero(keep)))
    (zg, sg, rg, ng), (zw, sw, rw, nw) = fits[True], fits[False]
    x, y = a + s_c * u
    return EdgeCrossing(float(x), float(y), zg - zw, float(np.hypot(sg, sw)), ng, nw, rg, rw)


def fit_flush_across_edges(crossings: Sequence[EdgeCrossing], *, max_rms_mm: float) -> FlushResult:
    """The glass's plane against the wall's from the steps at three or more crossings (weighted least squares).

    Raises FlushError when the crossings lie on one line (the tilt across it is unknown) or their
    steps do not lie on one plane within ``max_rms_mm``.
    """
    if len(crossings) < 3:
        raise FlushError(f"{len(crossings)} edge crossings; the flush's plane needs at least 3 (cross both edges)")
    xy = np.array([[c.x_mm, c.y_mm] for c in crossings])
    steps = np.array([c.step_mm for c in crossings])
    A = np.column_stack([np.ones(len(crossings)), -xy[:, 0], xy[:, 1]])  # step = dZ - dRy x + dRx y
    if np.linalg.matrix_rank(A) < 3:
        raise FlushError("the edge crossings lie on one line; cross both the top and the side edge")
    w = 1.0 / np.maximum([c.sigma_mm for c in crossings], MIN_STEP_SIGMA_MM)
    theta, *_ = np.linalg.lstsq(A * w[:, None], steps * w, rcond=None)
    residual = steps - A @ theta
    if len(crossings) > 3:
        rms = float(np.sqrt(np.sum(residual**2) / (len(crossings) - 3)))
        if rms > max_rms_mm:
            raise FlushError(
                f"the steps at the {len(crossings)} edge crossings do not lie on one plane (RMS {rms:.3f} mm > "
                f"{max_rms_mm:g} mm): the glass is bent or a crossing read another surface"
            )
    cov = np.linalg.inv((A * w[:, None] ** 2).T @ A)
    dz, dry, drx = (float(v) for v in theta)

    def pooled(values: list[float]) -> float:
        return float(np.sqrt(np.mean(np.square(values))))

    return FlushResult(
        dz_mm=dz,
        drx_rad=drx,
        dry_rad=dry,
        flush_mm=tuple(float(v) for v in steps),
        glass_rms_mm=pooled([c.glass_rms_mm for c in crossings]),
        wall_rms_mm=pooled([c.wall_rms_mm for c in crossings]),
        dz_sigma_mm=float(np.sqrt(cov[0, 0])),
    )


def flush_from_sweep(
    points_T: ArrayLike, legs: ArrayLike, path_mm: Sequence[ArrayLike], *, gap_mm: float, margin_mm: float, max_rms_mm: float
) -> tuple[FlushResult, list[EdgeCrossing]]:
    """The flush from a sweep's readings (K, 3) in T, each with its leg j (``path_mm[j]`` -> ``path_mm[j + 1]``):
    the step at each leg that crosses an edge, then the glass's plane against the wall's from them."""
    p = np.asarray(points_T, dtype=float)
    leg = np.asarray(legs)
    surface = surface_at(p[:, :2], gap_mm, margin_mm)
    crossings = []
    for j, start, end in crossing_legs(path_mm, gap_mm, margin_mm):
        on_leg = (leg == j) & (surface != 0)
        crossings.append(step_across_edge(p[on_leg], surface[on_leg] > 0, start, end, max_rms_mm=max_rms_mm))
    return fit_flush_across_edges(crossings, max_rms_mm=max_rms_mm), crossings
