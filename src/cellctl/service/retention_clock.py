"""Whether the wall clock can be trusted to age records: retention holds its pruning by age while it cannot.

A clock stepped a year ahead (a typo, a VM resumed with a bad clock, a wrong time server) would
make the next pass delete every cycle record, image and PLC idempotency key at once, and that
cannot be undone. :class:`ClockGuard` holds pruning by age (no I/O here: the pass gives it the
times and the newest cycle record) while either

- the wall time elapsed since the last pass disagrees with the monotonic time by more than
  :data:`STEP_MARGIN_S` (the clock was stepped), or
- at start (or while held), the wall clock is ahead of the newest cycle record by more than the shortest
  retention period; once held, the newest record stamped before the doubt counts (later ones carry the doubted clock).

Pruning by size needs no clock and goes on. The hold ends by itself once the clock is corrected.
"""

from __future__ import annotations

from datetime import datetime, timedelta

STEP_MARGIN_S = 600.0  # a wall-clock step smaller than this between two passes is not worth holding for

Newest = tuple[int, datetime]  # a cycle record's id and creation time


class ClockGuard:
    """Reviews the wall clock at each pass; :attr:`held` says why pruning by age is held (None: it is not)."""

    def __init__(self, margin_s: float = STEP_MARGIN_S) -> None:
        self.margin_s = margin_s
        self.held: str | None = None
        self.trusted_id: int | None = None  # while held: the newest cycle stamped before the clock was in doubt
        self._last: tuple[datetime, float] | None = None  # wall and monotonic time of the last pass
        self._seen_id = 0  # the newest cycle the last pass (with a trusted clock) saw

    def review(self, wall: datetime, mono: float, newest: Newest | None, period_days: float | None) -> str | None:
        """Why pruning by age is held now, or None. ``newest``: the newest cycle record, of those up to
        :attr:`trusted_id` while held; ``period_days``: the shortest retention period (None: none)."""
        step = None if self._last is None else (wall - self._last[0]).total_seconds() - (mono - self._last[1])
        continuous = self._last is not None and self.held is None  # the last pass trusted the clock
        self._last = (wall, mono)
        ahead = None if newest is None else wall - newest[1]
        if step is not None and abs(step) > self.margin_s:
            if self.trusted_id is None:
                self.trusted_id = self._seen_id  # records after the last pass may carry the stepped clock
            self.held = f"the wall clock jumped by {step / 3600:+.1f} h since the last retention pass (against the monotonic clock)"
        elif not continuous and ahead is not None and period_days is not None and ahead > timedelta(days=period_days):
            if self.trusted_id is None:
                self.trusted_id = newest[0] if newest is not None else 0
            self.held = (f"the wall clock is {ahead / timedelta(days=1):.0f} days ahead of the newest cycle record "
                         f"(cycle {self.trusted_id}), more than the shortest retention period ({period_days:g} days; "
                         "if the clock is right and the cell stood idle that long, restart the service once it has "
                         "recorded a cycle)")  # fmt: skip
        else:
            self.held, self.trusted_id = None, None
            self._seen_id = newest[0] if newest is not None else self._seen_id
        return self.held
