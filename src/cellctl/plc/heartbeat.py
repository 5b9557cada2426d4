"""PLC heartbeat supervision: the link is alive while ``plc_heartbeat`` keeps changing.

A counter watchdog (the sender changes a word, the receiver faults if it stays the same for the
timeout): a PLC that keeps writing the same value counts as silent. Pure logic; the caller supplies
the time, so tests need no clock.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class LinkEvent(enum.Enum):
    STARTED = "started"
    LOST = "lost"
    RESTORED = "restored"


@dataclass(frozen=True)
class LinkChange:
    event: LinkEvent
    silent_for_s: float
    """How long the heartbeat had been unchanged (for LOST); 0 otherwise."""


class HeartbeatWatch:
    """Reports STARTED at the heartbeat's first change, LOST once when it stays unchanged for
    ``timeout_s`` (also when it never started), and RESTORED once when it changes again after a
    reported loss.

    ``start_s`` None leaves the watch unarmed: changes are followed, but no loss is reported until
    :meth:`arm`, whose time opens the first window (the service is up only then).
    """

    def __init__(self, timeout_s: float, start_s: float | None, initial_value: int = 0) -> None:
        if not timeout_s > 0:
            raise ValueError(f"heartbeat timeout must be > 0 s, got {timeout_s}")
        self._timeout_s = timeout_s
        self._last_value = initial_value
        self._armed = start_s is not None
        self._last_change_s = 0.0 if start_s is None else start_s
        self._alive = False
        self._lost_reported = False
        self._started = False

    @property
    def alive(self) -> bool:
        """The heartbeat changed within the timeout."""
        return self._alive

    @property
    def armed(self) -> bool:
        """A loss can be reported (the first window has opened)."""
        return self._armed

    def arm(self, now_s: float) -> None:
        """Start supervising: the first window runs from ``now_s``. Arming an armed watch changes nothing."""
        if not self._armed:
            self._armed = True
            self._last_change_s = now_s

    def observe(self, value: int, now_s: float) -> LinkChange | None:
        """Feed one sample of ``plc_heartbeat``; returns a change of the link's state, if any."""
        if value != self._last_value:
            self._last_value = value
            self._last_change_s = now_s
            self._alive = True
            if self._lost_reported:
                self._lost_reported = False
                self._started = True
                return LinkChange(LinkEvent.RESTORED, 0.0)
            if not self._started:
                self._started = True
                return LinkChange(LinkEvent.STARTED, 0.0)
            return None
        silent = now_s - self._last_change_s
        if silent > self._timeout_s:
            self._alive = False
            if self._armed and not self._lost_reported:
                self._lost_reported = True
                return LinkChange(LinkEvent.LOST, silent)
        return None
