"""What a choice of wall readings buys: the predicted error of the fitted plane, for spots or a sweep.

Each reading's error along the wall normal is the laser's noise (independent per reading) plus the
robot's pose error, drawn once per standing stop: a spot read standing has its own draw, a reading
taken on the move between two stops blends theirs (the arm's error changes smoothly along a move),
so a long sweep has few independent draws however many readings it stores. The plane z = c0 + c1 x
+ c2 y is fitted (eq. 2-11 in the small-angle form) to many draws of these errors; the spread of its
tilt and of its offset at the corner is the prediction.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Readings:
    """Where readings fall on the wall and which robot stops their pose errors come from.

    Attributes:
        xy_mm: (N, 2) positions in the workpiece frame (x right, y down from the corner; mm).
        stops: (N, 2) the two stops each reading's robot error blends (equal for a standing read).
        blend: (N,) how far from the first stop to the second (0: the first's error).
        n_stops: how many stops (independent robot draws) there are.
    """

    xy_mm: F64
    stops: NDArray[np.intp]
    blend: F64
    n_stops: int


def standing_readings(spots_mm: ArrayLike) -> Readings:
    """One reading per spot, each at its own standing stop (stop and go)."""
    xy = np.asarray(spots_mm, dtype=float).reshape(-1, 2)
    k = np.arange(len(xy))
    return Readings(xy, np.column_stack([k, k]), np.zeros(len(xy)), len(xy))


def sweep_readings(path_mm: ArrayLike, spacing_mm: float) -> Readings:
    """Readings every ``spacing_mm`` along a path's legs; the path's corners are its stops."""
    corners = np.asarray(path_mm, dtype=float).reshape(-1, 2)
    if len(corners) < 2 or not spacing_mm > 0:
        raise ValueError("a sweep needs at least two corners and a positive spacing between readings")
    xy, stops, blend = [], [], []
    for k, (a, b) in enumerate(zip(corners[:-1], corners[1:])):
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / spacing_mm)))
        f = np.linspace(0.0, 1.0, n, endpoint=False)
        xy.append(a + np.outer(f, b - a))
        stops.append(np.tile([k, k + 1], (n, 1)))
        blend.append(f)
    return Readings(np.vstack(xy), np.vstack(stops), np.concatenate(blend), len(corners))


def predicted_plane_error(
    readings: Readings, *, laser_sigma_mm: float, robot_sigma_mm: float, draws: int = 400, seed: int = 0
) -> tuple[float, float]:
    """One-sigma error of the fitted plane: (tilt of its normal in deg, offset along the normal at the corner in mm)."""
    x, y = readings.xy_mm[:, 0], readings.xy_mm[:, 1]
    A = np.column_stack([np.ones_like(x), x, y])
    if np.linalg.matrix_rank(A) < 3:
        raise ValueError("the readings lie on a line: they cannot fix a plane; spread them in two directions")
    rng = np.random.default_rng(seed)
    robot = rng.normal(0.0, robot_sigma_mm, (draws, readings.n_stops))
    a, b = readings.stops[:, 0], readings.stops[:, 1]
    err = (1.0 - readings.blend) * robot[:, a] + readings.blend * robot[:, b]
    err += rng.normal(0.0, laser_sigma_mm, err.shape)
    c, *_ = np.linalg.lstsq(A, err.T, rcond=None)  # (3, draws)
    tilt = np.degrees(np.hypot(c[1], c[2]))
    return float(np.sqrt(np.mean(tilt**2))), float(np.std(c[0]))


def fastest_order(n: int, move_s: Callable[[int, int], float], *, first: int | None = None) -> tuple[list[int], float]:
    """The visiting order of ``n`` stops with the least total move time (every order for up to 8 stops, else nearest first)."""
    if n < 1:
        raise ValueError("no stops to order")
    starts = range(n) if first is None else [first]
    if n <= 8:
        best: tuple[float, Sequence[int]] = (float("inf"), [])
        for s in starts:
            for rest in itertools.permutations([k for k in range(n) if k != s]):
                order = (s, *rest)
                total = sum(move_s(i, j) for i, j in itertools.pairwise(order))
                best = min(best, (total, order), key=lambda b: b[0])
        return list(best[1]), best[0]
    order = [next(iter(starts))]
    while len(order) < n:
        order.append(min((k for k in range(n) if k not in order), key=lambda k: move_s(order[-1], k)))
    return order, sum(move_s(i, j) for i, j in itertools.pairwise(order))
