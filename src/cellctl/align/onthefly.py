"""Laser readings taken on the move: pair each with the flange pose at its instant, estimate the latency.

The laser stores readings at a fixed cycle (reading k stands for ``started_s + k * cycle_s`` on the
cell's clock) while the robot streams its flange pose T_B_H (mm) every few ms. Reading k truly
reflects the flange pose at ``instant_k - latency``; the laser point is then
P_k = T_B_H(instant_k - latency) @ (r + d_k l) (paper eq. 1). The latency is the one that puts the
points of a move against a flat wall on one plane (eq. 2-11), found by a coarse grid and a bounded
1-D refinement of the plane-fit residual. The cycle's sweep times the laser at one spot instead
(:mod:`cellctl.align.beam_timing`), where the robot's error from stop to stop cannot pass for latency.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation, Slerp

from cellctl.align.laser_points import check_laser_ray, laser_points
from cellctl.ports import PoseSample, StoredReadings

F64 = NDArray[np.float64]

GRID_STEP_S = 0.0005
MIN_READINGS = 20
# Below this RMS of the beam-direction speed a plane cannot absorb, the latency is not observable.
MIN_BEAM_SPEED_MM_S = 5.0
OBSERVABILITY_HINT = (
    "make a calibration move with speed along the beam that changes during the move and spots spread "
    "over the wall in two directions, e.g. 60 mm toward the wall while moving 60 mm sideways, then "
    "60 mm away while moving 60 mm in the other sideways direction (an L on the wall)"
)


class LatencyAtEdge(ValueError):
    """The best latency lies at the edge of the searched range: the true one may lie beyond it."""


class FlangeTrajectory:
    """The flange pose T_B_H (mm) at any instant between the first and the last feedback sample.

    Positions are interpolated linearly, rotations by Slerp (scipy).
    """

    def __init__(self, samples_t: ArrayLike, samples_T: ArrayLike) -> None:
        t = np.asarray(samples_t, dtype=float)
        T = np.asarray(samples_T, dtype=float)
        if t.ndim != 1 or t.size < 2:
            raise ValueError(f"need at least 2 feedback samples as a 1-D time array, got shape {t.shape}")
        if T.shape != (t.size, 4, 4):
            raise ValueError(f"samples_T must have shape ({t.size}, 4, 4), got {T.shape}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(T))):
            raise ValueError("feedback samples contain NaN or infinite values")
        if np.any(np.diff(t) <= 0):
            k = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise ValueError(f"feedback times must increase strictly; sample {k + 1} at {float(t[k + 1])!r} s does not")
        self._t = t
        self._p = T[:, :3, 3].copy()
        self._slerp = Slerp(t, Rotation.from_matrix(T[:, :3, :3]))

    @property
    def start_s(self) -> float:
        """The first sample's instant (s)."""
        return float(self._t[0])

    @property
    def end_s(self) -> float:
        """The last sample's instant (s)."""
        return float(self._t[-1])

    def __call__(self, t: ArrayLike) -> F64:
        """(M, 4, 4) flange poses at the instants ``t`` (s, cell clock); ValueError outside the samples."""
        q = np.atleast_1d(np.asarray(t, dtype=float))
        outside = ~((q >= self._t[0]) & (q <= self._t[-1]))
        if outside.any():
            i = int(np.flatnonzero(outside)[0])
            raise ValueError(
                f"instant {float(q[i])!r} s (index {i}) is outside the feedback samples "
                f"{float(self._t[0])!r}..{float(self._t[-1])!r} s; no flange pose is known there"
            )
        j = np.clip(np.searchsorted(self._t, q, side="right") - 1, 0, self._t.size - 2)
        w = (q - self._t[j]) / (self._t[j + 1] - self._t[j])
        out = np.zeros((q.size, 4, 4))
        out[:, :3, :3] = self._slerp(q).as_matrix()
        out[:, :3, 3] = self._p[j] + w[:, None] * (self._p[j + 1] - self._p[j])
        out[:, 3, 3] = 1.0
        return out


def flange_poses_at(samples_t: ArrayLike, samples_T: ArrayLike, t: ArrayLike) -> F64:
    """(M, 4, 4) flange poses T_B_H (mm) at instants ``t`` (s) from feedback samples (N,) and (N, 4, 4)."""
    return FlangeTrajectory(samples_t, samples_T)(t)


def pose_samples_arrays(samples: Sequence[PoseSample]) -> tuple[F64, F64]:
    """Feedback samples as (N,) instants (s) and (N, 4, 4) poses, time-sorted, repeated instants dropped."""
    t = np.array([s.t_s for s in samples], dtype=float)
    order = np.argsort(t, kind="stable")
    keep = order[np.concatenate([[True], np.diff(t[order]) > 0])] if t.size else order
    T = np.array([samples[int(i)].pose.to_matrix() for i in keep]).reshape(-1, 4, 4)
    return t[keep], T


def stored_instants(stored: StoredReadings) -> tuple[F64, F64]:
    """(K,) instants (s, cell clock: started_s + k * cycle_s) and distances (mm, NaN where none)."""
    k = np.arange(len(stored.distances_mm), dtype=float)
    d = np.array([np.nan if x is None else x for x in stored.distances_mm], dtype=float)
    return stored.started_s + k * stored.cycle_s, d


@dataclass(frozen=True)
class PairedReadings:
    """Stored readings with the flange pose each reflects.

    Attributes:
        poses: (K, 4, 4) flange poses T_B_H (mm) at ``instants - latency``.
        distances: (K,) distances along l from r (mm).
        instants: (K,) the readings' instants on the cell's clock (s), before the latency.
        indices: (K,) each reading's index k in the storage.
    """

    poses: F64
    distances: F64
    instants: F64
    indices: NDArray[np.intp]

    def points(self, r: ArrayLike, l: ArrayLike) -> F64:
        """(K, 3) laser points in the base frame (paper eq. 1)."""
        return laser_points(self.poses, r, l, self.distances)


def pair_stored_readings(
    stored: StoredReadings, samples: Sequence[PoseSample], latency_s: float, *, max_gap_s: float | None = None
) -> PairedReadings:
    """Pair each stored reading with the flange pose at its instant minus ``latency_s`` (s).

    Readings without a distance, those whose shifted instant lies outside the feedback, and (with
    ``max_gap_s``) those falling in a gap of the feedback longer than that (lost samples: no pose
    is guessed across it) are dropped.
    """
    instants, d = stored_instants(stored)
    t, T = pose_samples_arrays(samples)
    trajectory = FlangeTrajectory(t, T)
    q = instants - latency_s
    inside = np.isfinite(d) & (q >= trajectory.start_s) & (q <= trajectory.end_s)
    if max_gap_s is not None and t.size > 1:
        after = np.clip(np.searchsorted(t, q, side="left"), 1, t.size - 1)
        inside &= (t[after] - t[after - 1]) <= max_gap_s
    keep = np.flatnonzero(inside)
    return PairedReadings(trajectory(q[keep]).reshape(-1, 4, 4), d[keep], instants[keep], keep)


def standing(samples_t: ArrayLike, samples_T: ArrayLike, t: ArrayLike, *, hold_s: float = 0.03, tol_mm: float = 0.01) -> NDArray[np.bool_]:
    """(M,) whether the flange stood still at each instant ``t`` (s): its reported position moved at
    most ``tol_mm`` over the ``hold_s`` before (longer than the servo's lag, so the arm itself stood too).
    Instants whose window leaves the feedback samples count as moving."""
    trajectory = FlangeTrajectory(samples_t, samples_T)
    q = np.atleast_1d(np.asarray(t, dtype=float))
    inside = (q - hold_s >= trajectory.start_s) & (q <= trajectory.end_s)
    out = np.zeros(q.size, dtype=bool)
    if inside.any():
        now, before = trajectory(q[inside]), trajectory(q[inside] - hold_s)
        out[inside] = np.linalg.norm(now[:, :3, 3] - before[:, :3, 3], axis=1) <= tol_mm
    return out


@dataclass(frozen=True)
class LatencyEstimate:
    """The latency between the laser's instants and the flange feedback, from a move against a flat wall.

    Attributes:
        latency_s: the reading at instant t reflects the flange pose at t - latency_s (s).
        sigma_s: its standard deviation from the Jacobian of the plane residuals (s).
        rms_mm: RMS distance of the laser points from their plane at that latency (mm).
        n: readings used.
        beam_speed_mm_s: RMS of the point speed along the normal that no plane can absorb (mm/s; at one
            spot, along the beam); the latency's leverage (sigma_s = residual sigma / (this * sqrt(n))).
        normal: unit normal of the fitted wall plane (base frame); None when timed at one spot
            (:mod:`cellctl.align.beam_timing`, whose ``rms_mm`` is the spread along the beam).
        offset_mm: the plane's D: normal . p = D (mm); None with ``normal``.
    """

    latency_s: float
    sigma_s: float
    rms_mm: float
    n: int
    beam_speed_mm_s: float
    normal: F64 | None = None
    offset_mm: float | None = None


@dataclass(frozen=True)
class TimingReadings:
    """Readings to time the laser by: each with a distance and within the feedback for every latency searched.

    Attributes:
        trajectory: the flange feedback.
        instants, distances: (K,) the readings kept (s on the cell's clock; mm along l).
        r, l: the laser's origin (mm) and unit direction in the flange frame.
        search_s: the latencies searched (s), low < high.
    """

    trajectory: FlangeTrajectory
    instants: F64
    distances: F64
    r: F64
    l: F64
    search_s: tuple[float, float]

    @classmethod
    def checked(
        cls, instants: ArrayLike, distances: ArrayLike, samples_t: ArrayLike, samples_T: ArrayLike, r: ArrayLike,
        l: ArrayLike, search_s: tuple[float, float],
    ) -> TimingReadings:
        """The readings kept (NaN distances and those the search would shift off the feedback left out); ValueError
        on mismatched arrays, an empty search range or fewer than ``MIN_READINGS`` kept."""
        t_k = np.asarray(instants, dtype=float).reshape(-1)
        d = np.asarray(distances, dtype=float).reshape(-1)
        if t_k.shape != d.shape:
            raise ValueError(f"{t_k.size} instants but {d.size} distances; give one instant per reading")
        lo, hi = float(search_s[0]), float(search_s[1])
        if not lo < hi:
            raise ValueError(f"search_s must be (low, high) with low < high, got {search_s!r}")
        rv, lv = check_laser_ray(r, l)
        trajectory = FlangeTrajectory(samples_t, samples_T)
        keep = np.isfinite(d) & np.isfinite(t_k) & (t_k - hi >= trajectory.start_s) & (t_k - lo <= trajectory.end_s)
        if (n := int(keep.sum())) < MIN_READINGS:
            raise ValueError(
                f"only {n} readings have a distance and lie within the feedback for every latency in "
                f"{lo * 1e3:g}..{hi * 1e3:g} ms; need {MIN_READINGS}: record the feedback longer than the readings"
            )
        return cls(trajectory, t_k[keep], d[keep], rv, lv, (lo, hi))


def difference_latencies(latency_s: float, instants: F64, trajectory: FlangeTrajectory, h: float = 2e-4) -> tuple[float, float]:
    """The latencies ``h`` (s) either side of ``latency_s`` for a central difference, kept where every reading's
    shifted instant stays within the feedback."""
    lo = max(latency_s - h, float(instants.max()) - trajectory.end_s)
    hi = min(latency_s + h, float(instants.min()) - trajectory.start_s)
    return lo, hi


class _WallCost:
    """The laser points as a function of the latency, and their plane-fit residuals (eq. 1-11)."""

    def __init__(self, trajectory: FlangeTrajectory, instants: F64, d: F64, r: F64, l: F64) -> None:
        self.trajectory, self.instants, self.d, self.r, self.l = trajectory, instants, d, r, l

    def points(self, latency_s: float) -> F64:
        return laser_points(self.trajectory(self.instants - latency_s), self.r, self.l, self.d)

    def __call__(self, latency_s: float) -> float:
        """Mean squared distance of the points from their least-squares plane (mm^2; eq. 10-11)."""
        V = self.points(latency_s)
        V = V - V.mean(axis=0)
        return float(np.linalg.eigvalsh(V.T @ V)[0]) / V.shape[0]

    def plane(self, latency_s: float) -> tuple[F64, float, F64, F64]:
        """(normal, offset, in-plane axes (3, 2), residuals) of the least-squares plane."""
        P = self.points(latency_s)
        c = P.mean(axis=0)
        _, vecs = np.linalg.eigh((P - c).T @ (P - c))
        normal = vecs[:, 0]
        offset = float(normal @ c)
        return normal, offset, vecs[:, 1:], P @ normal - offset

    def leverage(self, latency_s: float, h: float = 2e-4) -> tuple[F64, F64]:
        """The residuals' derivative by the latency (mm/s) with the plane's own freedom projected out."""
        normal, _, axes, _ = self.plane(latency_s)
        P = self.points(latency_s)
        lo, hi = difference_latencies(latency_s, self.instants, self.trajectory, h)
        J = (self.points(hi) - self.points(lo)) @ normal / (hi - lo)
        nuisance = np.column_stack([(P - P.mean(axis=0)) @ axes, np.ones(P.shape[0])])
        coef = np.linalg.lstsq(nuisance, J, rcond=None)[0]
        return J - nuisance @ coef, normal


def estimate_latency(
    instants: ArrayLike,
    distances: ArrayLike,
    samples_t: ArrayLike,
    samples_T: ArrayLike,
    r: ArrayLike,
    l: ArrayLike,
    *,
    search_s: tuple[float, float] = (-0.01, 0.05),
    min_beam_speed_mm_s: float = MIN_BEAM_SPEED_MM_S,
) -> LatencyEstimate:
    """The latency (s) that puts the laser points of a move against a flat wall on one plane.

    Args:
        instants: (K,) the readings' instants on the cell's clock (s).
        distances: (K,) distances along l from r (mm); NaN readings are left out.
        samples_t, samples_T: the flange feedback, (N,) instants (s) and (N, 4, 4) poses T_B_H (mm).
        r, l: laser origin (mm) and unit direction in the flange frame (eq. 1).
        search_s: the latencies considered (s); readings whose shifted instants leave the feedback
            anywhere in this range are left out.
        min_beam_speed_mm_s: the least RMS beam-direction point speed (mm/s) a plane cannot absorb.

    Raises:
        ValueError: too few readings, a latency at the edge of the search range, or a move from
            which the latency is not observable (it says which move to make instead).
    """
    timed = TimingReadings.checked(instants, distances, samples_t, samples_T, r, l, search_s)
    trajectory, (lo, hi), n = timed.trajectory, timed.search_s, timed.instants.size
    cost = _WallCost(trajectory, timed.instants, timed.distances, timed.r, timed.l)
    P = cost.points(0.5 * (lo + hi))
    spread = np.sqrt(np.clip(np.linalg.eigvalsh(np.cov(P.T)), 0.0, None))
    if spread[1] < 1e-3 * spread[2] or spread[1] < 1.0:
        raise ValueError(
            f"the laser spots lie on a line or one spot (spread {spread[2]:.3g} by {spread[1]:.3g} mm), "
            f"so no wall plane is defined and the latency is not observable; {OBSERVABILITY_HINT}"
        )

    def observable(latency_s: float) -> None:
        beam_speed = float(np.sqrt(np.mean(cost.leverage(latency_s)[0] ** 2)))
        if beam_speed < min_beam_speed_mm_s:
            raise ValueError(
                f"the latency is not observable from this move: the distances barely change "
                f"(spread {np.ptp(timed.distances):.3g} mm) and the point speed along the wall normal that no plane "
                f"can absorb is {beam_speed:.3g} mm/s RMS (need {min_beam_speed_mm_s:g}); {OBSERVABILITY_HINT}"
            )

    latency = best_latency(cost, timed.search_s, observable)
    normal, offset, _, residuals = cost.plane(latency)
    J, _ = cost.leverage(latency)
    sigma_mm = float(np.sqrt(np.sum(residuals**2) / max(n - 4, 1)))
    sigma_s = sigma_mm / float(np.linalg.norm(J))
    return LatencyEstimate(
        latency_s=latency,
        sigma_s=sigma_s,
        rms_mm=float(np.sqrt(np.mean(residuals**2))),
        n=n,
        beam_speed_mm_s=float(np.sqrt(np.mean(J**2))),
        normal=normal,
        offset_mm=offset,
    )


def best_latency(cost: Callable[[float], float], search_s: tuple[float, float], observable: Callable[[float], None]) -> float:
    """The latency (s) with the least ``cost`` in ``search_s``: a grid every ``GRID_STEP_S``, ``observable`` told its
    best (it raises when the move cannot show the latency), then a bounded 1-D refinement between its neighbours.

    Raises:
        LatencyAtEdge: the grid's best lies at an edge of the range.
    """
    lo, hi = search_s
    grid = np.linspace(lo, hi, max(round((hi - lo) / GRID_STEP_S), 2) + 1)
    i = int(np.argmin([cost(float(x)) for x in grid]))
    observable(float(grid[i]))
    if i == 0 or i == grid.size - 1:
        raise LatencyAtEdge(
            f"the best latency lies at the edge of the search range {lo * 1e3:g}..{hi * 1e3:g} ms "
            f"({grid[i] * 1e3:g} ms); widen search_s"
        )
    res = minimize_scalar(cost, bounds=(float(grid[i - 1]), float(grid[i + 1])), method="bounded", options={"xatol": 1e-8})
    return float(res.x)


def even_along_path(poses: ArrayLike, keep: int) -> NDArray[np.intp]:
    """Indices of at most ``keep`` of the flange poses (N, 4, 4) spread evenly along the path by distance
    travelled, not by time: readings crowd where the arm ramps its speed and pile up where it stands."""
    p = np.asarray(poses, dtype=float)[:, :3, 3]
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    if len(p) <= keep or travelled[-1] <= 0.0:
        return np.arange(len(p))
    return np.unique(np.searchsorted(travelled, np.linspace(0.0, travelled[-1], keep)).clip(0, len(p) - 1))


def at_corners(
    poses: ArrayLike, at_rest: ArrayLike, corners: Sequence[ArrayLike], within_mm: float, *, stop_of: ArrayLike | None = None
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The readings taken standing (``at_rest``, (N,) bool) with the flange within ``within_mm`` of a corner's
    position (not out along the beam while the laser is timed), and the corner of each: (M,) indices, (M,) corners.

    ``stop_of`` (N,) is the corner whose stop each reading fell in, by time; a path that comes back to a corner
    then counts its two stops apart. Without it, each reading counts at the nearest corner."""
    rest = np.flatnonzero(np.asarray(at_rest, dtype=bool))
    if not len(corners) or not rest.size:
        return rest[:0], rest[:0]
    at = np.array([np.asarray(T, dtype=float)[:3, 3] for T in corners])
    gaps = np.linalg.norm(np.asarray(poses, dtype=float)[rest, None, :3, 3] - at[None], axis=2)
    corner = np.argmin(gaps, axis=1) if stop_of is None else np.clip(np.asarray(stop_of, dtype=np.intp)[rest], 0, len(at) - 1)
    keep = gaps[np.arange(rest.size), corner] <= within_mm
    return rest[keep], corner[keep]
