"""Timing the laser from moves along its beam: the spot stays on one wall point, so at the right latency
the laser points P_k = T_B_H(t_k - latency) @ (r + d_k l) (paper eq. 1) coincide.

No wall plane is fitted, unlike :func:`cellctl.align.onthefly.estimate_latency` over a whole sweep:
there the robot's error, drawn anew at every stop, sets the legs of a sweep apart along the normal by
some hundredths of a millimetre, which a latency shifting each leg along its own direction can mimic
on a tilted wall (a millisecond off, seen in the twin). Along the beam at one spot that error only
blends from one stand to the next, odd about a move's middle, while the latency's trace follows the
speed, even about it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cellctl.align.laser_points import laser_points
from cellctl.align.onthefly import (
    MIN_BEAM_SPEED_MM_S,
    FlangeTrajectory,
    LatencyEstimate,
    TimingReadings,
    best_latency,
    difference_latencies,
)

F64 = NDArray[np.float64]

MAX_ACROSS_BEAM_MM = 1.0  # the flange's travel across the beam: beyond it the spot moves on the wall
ALONG_BEAM_HINT = "move the flange along the laser beam at one spot on the wall (process.align.sweep.approach_mm)"


class _SpotCost:
    """The laser points of moves along the beam as a function of the latency, and their spread along it."""

    def __init__(self, trajectory: FlangeTrajectory, instants: F64, d: F64, r: F64, l: F64, beam: F64) -> None:
        self.trajectory, self.instants, self.d, self.r, self.l, self.beam = trajectory, instants, d, r, l, beam

    def along(self, latency_s: float) -> F64:
        """(K,) each point's offset along the beam from their mean (mm)."""
        e = laser_points(self.trajectory(self.instants - latency_s), self.r, self.l, self.d) @ self.beam
        return e - e.mean()

    def __call__(self, latency_s: float) -> float:
        return float(np.mean(self.along(latency_s) ** 2))

    def rate(self, latency_s: float) -> F64:
        """(K,) d(offset along the beam)/d(latency) (mm/s), by central difference."""
        lo, hi = difference_latencies(latency_s, self.instants, self.trajectory)
        return (self.along(hi) - self.along(lo)) / (hi - lo)


def estimate_latency_at_spot(timed: TimingReadings, *, min_beam_speed_mm_s: float = MIN_BEAM_SPEED_MM_S) -> LatencyEstimate:
    """The latency (s) that puts the laser points of moves along the beam (one wall spot) on one point.

    ``timed`` are the readings of those moves with the flange feedback and the latencies to search
    (:meth:`TimingReadings.checked`). The estimate's ``rms_mm`` is the points' spread along the beam;
    it has no plane (``normal`` None).

    Raises:
        ValueError: a flange that moved across the beam (the spot wandered), a move too short along
            the beam to show the latency, or (LatencyAtEdge) a latency at the search range's edge.
    """
    trajectory, (lo, hi), n, t_k = timed.trajectory, timed.search_s, timed.instants.size, timed.instants
    flange = trajectory(t_k - 0.5 * (lo + hi))
    beam = np.einsum("nij,j->i", flange[:, :3, :3], timed.l)
    beam /= np.linalg.norm(beam)
    travel = flange[:, :3, 3] - flange[:, :3, 3].mean(axis=0)
    across = float(np.max(np.linalg.norm(travel - np.outer(travel @ beam, beam), axis=1)))
    if across > MAX_ACROSS_BEAM_MM:
        raise ValueError(
            f"the flange moved up to {across:.3g} mm across the laser beam (at most {MAX_ACROSS_BEAM_MM:g}): "
            f"the spot left its place on the wall; {ALONG_BEAM_HINT}"
        )
    cost = _SpotCost(trajectory, t_k, timed.distances, timed.r, timed.l, beam)

    def observable(latency_s: float) -> None:
        beam_speed = float(np.sqrt(np.mean(cost.rate(latency_s) ** 2)))
        if beam_speed < min_beam_speed_mm_s:
            raise ValueError(
                f"the latency is not observable: the points move along the beam at {beam_speed:.3g} mm/s RMS with it "
                f"(need {min_beam_speed_mm_s:g}); {ALONG_BEAM_HINT}, longer or faster"
            )

    latency = best_latency(cost, timed.search_s, observable)
    e = cost.along(latency)
    J = cost.rate(latency)
    sigma_mm = float(np.sqrt(np.sum(e**2) / max(n - 2, 1)))
    return LatencyEstimate(
        latency_s=latency,
        sigma_s=sigma_mm / float(np.linalg.norm(J)),
        rms_mm=float(np.sqrt(np.mean(e**2))),
        n=n,
        beam_speed_mm_s=float(np.sqrt(np.mean(J**2))),
    )

