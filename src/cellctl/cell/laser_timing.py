"""The laser-to-robot latency kept from one sweep to the next (issue 19: estimated, and checked online).

Timing the laser against the robot's feedback takes three moves along the beam (in, out and in:
what depends on where the flange is cancels between them). The latency belongs to the devices,
not to the car body (but for how late the host noticed the storage's start, anew in each sweep:
:mod:`cellctl.cell.sweep_start` bounds it), so the cell times it in its first sweep, every ``retime_every`` sweeps, after a
failed cycle and after a check that disagreed; each sweep between moves in once along the beam and
checks the kept latency against that move. A check that disagrees by more than the tolerance gives
its own estimate to that sweep and asks the next one to time anew.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from cellctl.align.onthefly import LatencyEstimate
from cellctl.cell.sweep_start import StartWindow, SweepLatency

BeamMoves = Literal[1, 3]


@dataclass
class LaserTiming:
    """What the cell knows of the latency between its laser's readings and its robot's feedback.

    Attributes:
        latency_s: the kept latency (s), from the last timing; None until one.
        sigma_s: its standard deviation (s).
        sweeps_since: sweeps since that timing.
        devices: the laser and robot it was timed with (another pair is timed anew).
        retime_reason: why the next sweep times anew (None: it checks, unless due or never timed).
        last_sweep: the last alignment sweep's own latency and its storage's start window (the flush sweep
            takes its latency from it, :mod:`cellctl.cell.sweep_start`).
        start: the storage start window of the sweep that timed ``latency_s`` (a checking sweep moves the kept
            latency from it to its own start, as the flush sweep does; None: the driver gives no window).
    """

    latency_s: float | None = None
    sigma_s: float | None = None
    sweeps_since: int = 0
    devices: tuple[object, object] | None = None  # the objects, not id()s: a replaced driver may reuse a freed id
    retime_reason: str | None = None
    last_sweep: SweepLatency | None = None
    start: StartWindow | None = None

    def why_time(self, laser: object, robot: object, retime_every: int) -> str | None:
        """Why the coming sweep times the laser (three moves along the beam); None: it checks the kept latency."""
        if self.latency_s is None:
            return "no latency kept yet (the first sweep since the service started)"
        if self.devices is None or self.devices[0] is not laser or self.devices[1] is not robot:
            return "the laser or the robot is another device than the one timed"
        if self.retime_reason is not None:
            return self.retime_reason
        if self.sweeps_since + 1 >= retime_every:
            return f"{retime_every} sweeps since the last timing (process.align.sweep.retime_every)"
        return None

    def timed(self, estimate: LatencyEstimate, laser: object, robot: object, start: StartWindow | None = None) -> None:
        """A sweep timed the laser (its storage started in ``start``): keep its estimate."""
        self.latency_s, self.sigma_s, self.sweeps_since = estimate.latency_s, estimate.sigma_s, 0
        self.devices, self.retime_reason, self.start = (laser, robot), None, start

    def kept_at(self, start: StartWindow | None) -> tuple[float, float]:
        """The kept latency (s) for a sweep whose storage started in ``start``, and the most it can be off (s)."""
        assert self.latency_s is not None, "why_time() said to time first"
        return SweepLatency(self.latency_s, self.sigma_s, "timed", self.start, self.latency_s).moved_to(start)

    def checked(
        self, estimate: LatencyEstimate, tolerance_s: float, start: StartWindow | None = None
    ) -> tuple[float, dict[str, Any]]:
        """A sweep (its storage started in ``start``) checked the kept latency: the latency it uses, and the check's
        figures for the record.

        The kept latency is moved from its timing sweep's storage start to this one's (how late the host noticed
        each start differs, :mod:`cellctl.cell.sweep_start`). Within ``tolerance_s`` of the check it stays (timed on
        three moves, it is the better one); beyond, the sweep uses the check's and the next sweep times anew.
        """
        kept_s, bound_s = self.kept_at(start)
        self.sweeps_since += 1
        off_s = estimate.latency_s - kept_s
        agrees = abs(off_s) <= tolerance_s
        figures = {"kept_ms": 1e3 * kept_s, "kept_timed_ms": 1e3 * self.latency_s, "kept_bound_ms": 1e3 * bound_s,
                   "checked_ms": 1e3 * estimate.latency_s, "checked_sigma_ms": 1e3 * estimate.sigma_s, "off_ms": 1e3 * off_s,
                   "agrees": agrees}  # fmt: skip
        if agrees:
            return kept_s, figures
        self.retime_reason = (
            f"the last check found {1e3 * estimate.latency_s:.2f} ms against the kept {1e3 * kept_s:.2f} ms "
            f"(tolerance {1e3 * tolerance_s:g} ms)"
        )
        return estimate.latency_s, figures

    def forget(self, reason: str) -> None:
        """Time anew in the next sweep (a failed cycle: a device may have been restarted or swapped)."""
        if self.latency_s is not None:
            self.retime_reason = reason
