"""Flush on the move: the step between glass and wall where one continuous leg of the sweep crosses an edge.

A sweep's leg carries the robot's error of that move: the ends' errors blended along the path,
the deflection at speed, the accuracy field along the way. Readings on the glass and on the wall
taken on *one* leg, a few centimetres either side of the edge, carry nearly the same error, so
their difference is the flush; read on separate legs they carry the two legs' independent errors.

Per crossing leg, the heights (z in T, mm) on both sides, in windows mirrored about the leg's
middle (which lies in the gap), are fitted as one model in the position x from that middle: the
step between the surfaces, the leg's error linear in x, and terms even in x (|x|, x^2) for what is
symmetric about the middle: the deflection of a short leg's speed profile, the curvature of the
accuracy field, the surfaces' slopes differing by their tilt. The step is the flush there. The steps at three or
more crossings then give the glass's plane against the wall's as in :mod:`cellctl.inspection.flush`:
``step = dZ - dRy x + dRx y`` at the crossing point (x, y).

Glass and wall are told apart by the outline of the recipe's own opening (:class:`Opening`: its far sides
and rounded corners): past a far side lies the wall the alignment fits too, and a leg across a far edge is
a crossing like one beside the corner.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.inspection.flush import FlushError, FlushResult

MIN_SIDE_READINGS = 4  # per side of a crossing (the model has five terms)
MIN_STEP_SIGMA_MM = 0.001  # a crossing's weight is capped here: its lines' scatter does not see every error
MIN_SPREAD_MM = 100.0  # the crossings span at least this in x and in y: the tilt about each axis needs a base
MIN_BEYOND_MM = 10.0  # a crossing leg runs at least this far past the gap's margin on both sides (its readings)


@dataclass(frozen=True)
class EdgeCrossing:
    """The step at one leg's crossing of an edge, in the measured workpiece frame T.

    Attributes:
        x_mm, y_mm: the crossing point (the leg's middle, in the gap).
        step_mm: the glass's height over the wall's there (+ = into the wall, as dZ).
        sigma_mm: the step's 1-sigma from the fit's residual.
        glass_readings, wall_readings: readings fitted on each side (mirrored windows).
        glass_rms_mm, wall_rms_mm: the fit's RMS residual on each side.
    """

    x_mm: float
    y_mm: float
    step_mm: float
    sigma_mm: float
    glass_readings: int
    wall_readings: int
    glass_rms_mm: float
    wall_rms_mm: float


@dataclass(frozen=True)
class Opening:
    """The window opening's outline in T (mm): x in [-width, 0], y in [0, height], its corners rounded by the radius."""

    width_mm: float
    height_mm: float
    corner_radius_mm: float


UNBOUNDED = Opening(np.inf, np.inf, 0.0)  # no far sides, square corners: only the top and the right edge


def in_rounded_rect(xy: ArrayLike, left: float, right: float, top: float, bottom: float, radius: float) -> NDArray[np.bool_]:
    """(N,) whether points (x, y; T, mm, y down) lie strictly inside the rectangle with corners rounded by ``radius`` (mm)."""
    p = np.atleast_2d(np.asarray(xy, dtype=float))
    x, y = p[:, 0], p[:, 1]
    inside = (left < x) & (x < right) & (top < y) & (y < bottom)
    r = max(min(radius, (right - left) / 2.0, (bottom - top) / 2.0), 0.0)
    cx = np.minimum(np.maximum(x, left + r), right - r)  # the nearest corner arc's centre, or the point itself off the corners
    cy = np.minimum(np.maximum(y, top + r), bottom - r)
    return inside & (((cx == x) & (cy == y)) | (np.hypot(x - cx, y - cy) < r))


def surface_at(xy: ArrayLike, gap_mm: float, margin_mm: float, opening: Opening | None = None) -> NDArray[np.int_]:
    """(N,) +1 where a point (x, y in T, mm) lies on the glass (the opening inset by ``gap_mm``, its corners rounded
    by the opening's radius less the gap), -1 on the wall (outside the opening: beyond its far sides too), 0 in the
    gap or within ``margin_mm`` of an edge. ``opening`` None: :data:`UNBOUNDED` (x < 0 and y > 0 of T)."""
    o = UNBOUNDED if opening is None else opening
    w, h, r, d, m = o.width_mm, o.height_mm, o.corner_radius_mm, gap_mm + margin_mm, margin_mm
    glass = in_rounded_rect(xy, -w + d, -d, d, h - d, r - d)  # an inward offset by d rounds the corners r - d
    wall = ~in_rounded_rect(xy, -w - m, m, -m, h + m, r + m)  # an outward offset by m rounds them r + m
    return glass.astype(int) - wall.astype(int)


Leg = tuple[int, NDArray[np.float64], NDArray[np.float64]]  # (j, start, end): corners j -> j + 1 of a path, mm in T


def crossing_legs(path_mm: Sequence[ArrayLike], gap_mm: float, margin_mm: float, opening: Opening | None = None) -> list[Leg]:
    """The legs of a sweep path (corners in T, mm) that run from one surface to the other of ``opening`` (see
    :func:`surface_at`): (j, start, end), leg j being corners j -> j + 1."""
    corners = np.asarray(path_mm, dtype=float)
    surface = surface_at(corners, gap_mm, margin_mm, opening)
    return [(j, corners[j], corners[j + 1]) for j in range(len(corners) - 1) if surface[j] * surface[j + 1] < 0]


def crossing_path_problem(
    path_mm: Sequence[ArrayLike], gap_mm: float, margin_mm: float, opening: Opening | None = None
) -> str | None:
    """What keeps a sweep path from giving the flush on the move across the edges of ``opening``, or None: at least
    three crossing legs, each running from ``MIN_BEYOND_MM`` past the gap's margin on one side to as far on the
    other with its middle in the gap (the glass and the opening are convex: such a leg crosses one edge, once),
    spread over both directions."""
    legs = crossing_legs(path_mm, gap_mm, margin_mm, opening)
    if len(legs) < 3:
        return (f"it crosses an edge on {len(legs)} legs (a leg from a point on the glass, inside its edge by more "
                "than sweep_margin_mm, to one on the wall, or back); the flush needs at least three, on both edges"
                + _beyond_the_far_sides(path_mm, opening))  # fmt: skip
    short = [[a.tolist(), b.tolist()] for _, a, b in legs
             if np.any(surface_at(np.stack([a, b]), gap_mm, margin_mm + MIN_BEYOND_MM, opening) == 0)]  # fmt: skip
    if short:
        return f"the crossing legs {short} end less than {MIN_BEYOND_MM:g} mm past the gap's margin: lengthen them across the edge"
    middles = np.array([(a + b) / 2 for _, a, b in legs])
    off_gap = [m.tolist() for m in middles if surface_at(m, gap_mm, margin_mm, opening)[0] != 0]
    if off_gap:
        return f"the crossing legs' middles {off_gap} lie outside the gap (and its margins): centre each crossing leg on the gap"
    return spread_problem(middles)


def _size(opening: Opening | None) -> str:
    """The opening's size and place in T, for a message ("" without one)."""
    if opening is None:
        return ""
    o = opening
    return (f" ({o.width_mm:g} x {o.height_mm:g} mm, corner radius {o.corner_radius_mm:g}: x in [{-o.width_mm:g}, 0], "
            f"y in [0, {o.height_mm:g}] of T)")  # fmt: skip


def _beyond_the_far_sides(path_mm: Sequence[ArrayLike], opening: Opening | None) -> str:
    """The path's corners beyond the opening's far sides (on the wall), said with what to do; "" if none."""
    if opening is None:
        return ""
    corners = np.asarray(path_mm, dtype=float)
    far = [c.tolist() for c in corners if c[0] < -opening.width_mm or c[1] > opening.height_mm]
    if not far:
        return ""
    return (f"; its corners {far} lie beyond the far sides of this opening{_size(opening)}, on the wall: "
            "lay the legs across this opening's edges")


def spread_problem(xy: NDArray[np.float64]) -> str | None:
    """Why crossings at ``xy`` (N, 2; mm) cannot give both tilts, or None."""
    span = np.ptp(xy, axis=0)
    if np.any(span < MIN_SPREAD_MM) or np.linalg.matrix_rank(np.column_stack([np.ones(len(xy)), xy])) < 3:
        return (f"the edge crossings span {span[0]:.0f} mm in x and {span[1]:.0f} mm in y (at least {MIN_SPREAD_MM:g} each, "
                "not on one line): cross both the top and the side edge, near the corner and far from it")  # fmt: skip
    return None


def step_across_edge(
    points_T: ArrayLike, on_glass: ArrayLike, start_xy: ArrayLike, end_xy: ArrayLike, *, max_rms_mm: float
) -> EdgeCrossing:
    """The flush step where the leg from ``start_xy`` to ``end_xy`` (mm in T) crosses from one surface to the other.

    ``points_T`` (N, 3) are the leg's readings in T, ``on_glass`` (N,) True for the glass's and False
    for the wall's (readings in the gap already left out). Raises FlushError when a side has too few
    readings, the sides overlap along the leg (it crosses more than one edge), the leg's middle is not
    in the gap, or a side's RMS residual exceeds ``max_rms_mm``.
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
    # Windows mirrored about s_c, inside and out (the gap need not be centred on it).
    inner = max(s_c - first.max(), second.min() - s_c)
    reach = min(s_c - first.min(), second.max() - s_c)
    keep = (np.abs(s - s_c) >= inner - 1e-9) & (np.abs(s - s_c) <= reach + 1e-9)
    counts = {side: int(np.count_nonzero(keep & (glass == side))) for side in (True, False)}
    if min(counts.values()) < MIN_SIDE_READINGS:
        raise FlushError(
            f"a side of the crossing at {(a + s_c * u).round(1).tolist()} mm keeps too few readings in its mirrored window {counts}"
        )
    x, on_glass, z = s[keep] - s_c, glass[keep], p[keep, 2]
    # One model for both sides: the step, the leg's error (linear in x) and what is even about the middle
    # (|x|: with x it lets the surfaces' slopes differ; x^2: the deflection's and the accuracy field's curvature).
    A = np.column_stack([on_glass.astype(float), np.ones_like(x), x, np.abs(x), x**2])
    coef, *_ = np.linalg.lstsq(A, z, rcond=None)
    residual = z - A @ coef
    rms = {side: float(np.sqrt(np.mean(residual[on_glass == side] ** 2))) for side in (True, False)}
    for side, what in ((True, "glass"), (False, "wall")):
        if rms[side] > max_rms_mm:
            raise FlushError(
                f"the {what} readings beside the crossing at {(a + s_c * u).round(1).tolist()} mm scatter by {rms[side]:.3f} mm "
                f"(> {max_rms_mm:g} mm): a reading off another surface; check the sweep's legs against the opening"
            )
    sigma = float(np.sqrt(residual @ residual / max(len(z) - A.shape[1], 1) * np.linalg.inv(A.T @ A)[0, 0]))
    px, py = a + s_c * u
    return EdgeCrossing(float(px), float(py), float(coef[0]), sigma, counts[True], counts[False], rms[True], rms[False])


def fit_flush_across_edges(crossings: Sequence[EdgeCrossing], *, max_rms_mm: float) -> FlushResult:
    """The glass's plane against the wall's from the steps at three or more crossings (weighted least squares).

    Raises FlushError when the crossings do not span both directions (a tilt would be unknown) or
    their steps do not lie on one plane within ``max_rms_mm``.
    """
    if len(crossings) < 3:
        raise FlushError(f"{len(crossings)} edge crossings; the flush's plane needs at least 3 (cross both edges)")
    xy = np.array([[c.x_mm, c.y_mm] for c in crossings])
    steps = np.array([c.step_mm for c in crossings])
    A = np.column_stack([np.ones(len(crossings)), -xy[:, 0], xy[:, 1]])  # step = dZ - dRy x + dRx y
    problem = spread_problem(xy)
    if problem is not None:
        raise FlushError(problem)
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
    points_T: ArrayLike, legs: ArrayLike, path_mm: Sequence[ArrayLike], *, gap_mm: float, margin_mm: float, max_rms_mm: float,
    opening: Opening | None = None,
) -> tuple[FlushResult, list[EdgeCrossing], list[str]]:
    """The flush from a sweep's readings (K, 3) in T, each with its leg j (``path_mm[j]`` -> ``path_mm[j + 1]``;
    -1: none): the step at each leg that crosses an edge of ``opening`` (glass and wall told apart by its
    outline: :func:`surface_at`), then the glass's plane against the wall's from them. A crossing that cannot
    give its step is left out with its reason (the third list) while the others still span both edges; else
    FlushError names them all."""
    p = np.asarray(points_T, dtype=float)
    leg = np.asarray(legs)
    surface = surface_at(p[:, :2], gap_mm, margin_mm, opening)
    crossings: list[EdgeCrossing] = []
    missing: list[str] = []
    for j, start, end in crossing_legs(path_mm, gap_mm, margin_mm, opening):
        on_leg = (leg == j) & (surface != 0)
        try:
            crossings.append(step_across_edge(p[on_leg], surface[on_leg] > 0, start, end, max_rms_mm=max_rms_mm))
        except FlushError as err:
            missing.append(f"leg {j}: {err}")
    try:
        return fit_flush_across_edges(crossings, max_rms_mm=max_rms_mm), crossings, missing
    except FlushError as err:
        raise FlushError("; ".join([str(err), *missing])) from None
