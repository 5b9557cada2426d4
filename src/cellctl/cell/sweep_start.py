"""When a sweep's laser storage started, and the latency the inspection's flush sweep takes from the alignment's.

The LK-G driver stamps the storage's start at the ``AS`` echo's arrival as the host noticed it, so how
late the event loop noticed it (0.2 ms on a quiet PC, 20-115 ms on a loaded one) is in each sweep's
latency, anew in every sweep. The driver also gives the window the start lies in (the ``AS`` write to
the echo noticed, ``storage_start_window``): the start is known within that window whatever the split
(a prompt controller and a late host, or a late fake sharing the host). A sweep whose window is wider
than the latency check's tolerance starts its storage again (``RESTARTS`` times at most) before the
robot moves.

The flush sweep does not time the laser: it takes the alignment sweep's own estimate and moves it from
that sweep's window to its own, both referred to their windows' middles. It is then off by at most half
the two windows together (the estimate's own sigma aside); beyond the tolerance it is refused. A checking
alignment sweep moves the kept latency the same way, from the timing sweep's window to its own
(:meth:`cellctl.cell.laser_timing.LaserTiming.kept_at`), and searches near it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from cellctl.ports import StoringSensor

RESTARTS = 3  # storage starts again at most this often while its start is not known within the tolerance
How = Literal["timed", "checked", "fixed"]


@dataclass(frozen=True)
class StartWindow:
    """A storage's start (s, cell clock): the instant its readings are stamped from, and the window it lies in."""

    stamp_s: float
    earliest_s: float
    latest_s: float
    restarts: int = 0

    @property
    def width_s(self) -> float:
        """How well the start is known (s): the ``AS`` write to its echo noticed."""
        return self.latest_s - self.earliest_s

    @property
    def stamp_past_middle_s(self) -> float:
        """The stamp less the window's middle (s): what a latency referred to the stamp holds of this window."""
        return self.stamp_s - 0.5 * (self.earliest_s + self.latest_s)

    def figures(self) -> dict[str, Any]:
        return {"window_ms": 1e3 * self.width_s, "stamp_past_middle_ms": 1e3 * self.stamp_past_middle_s,
                "restarts": self.restarts}  # fmt: skip


@dataclass(frozen=True)
class SweepLatency:
    """A sweep's own latency (s, referred to its storage stamp), how it was found, and its storage's start window.

    Attributes:
        latency_s: the sweep's own estimate (timed or checked), or the configured one (fixed).
        sigma_s: the estimate's standard deviation (s); None when fixed.
        how: "timed", "checked" or "fixed".
        start: the storage's start window; None when the laser driver gives none (its stamp taken as exact).
        paired_s: the latency that sweep's readings were paired with (s).
    """

    latency_s: float
    sigma_s: float | None
    how: How
    start: StartWindow | None
    paired_s: float

    def moved_to(self, start: StartWindow | None) -> tuple[float, float]:
        """The latency (s) for a sweep whose storage started in ``start``, and the most it can be off (s)."""
        past = 0.0 if self.start is None else self.start.stamp_past_middle_s
        half = 0.0 if self.start is None else 0.5 * self.start.width_s
        if start is None:
            return self.latency_s - past, half
        return self.latency_s - past + start.stamp_past_middle_s, half + 0.5 * start.width_s


def start_window(laser: StoringSensor, stamp_s: float, restarts: int = 0) -> StartWindow | None:
    """The window the laser's last storage started in, or None when its driver gives none."""
    given = getattr(laser, "storage_start_window", None)
    window = given() if callable(given) else None
    if window is None:
        return None
    earliest, latest = (float(x) for x in window)
    return StartWindow(stamp_s, earliest, latest, restarts)


async def start_known(laser: StoringSensor, *, cycle_s: float, count: int, timeout_s: float, within_s: float) -> StartWindow | None:
    """Start the laser's storage; again (at most ``RESTARTS`` times) while its start is not known within ``within_s``.

    The last start's window, or None when the driver gives none.
    """
    restarts = 0
    while True:
        stamp = await laser.start_storage(cycle_s=cycle_s, count=count, timeout_s=timeout_s)
        window = start_window(laser, stamp, restarts)
        if window is None or window.width_s <= within_s or restarts >= RESTARTS:
            return window
        restarts += 1
