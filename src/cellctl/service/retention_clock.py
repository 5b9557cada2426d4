"""Whether the wall clock can be trusted to age records: retention holds its pruning by age while it cannot.

A clock stepped a year ahead (a typo, a VM resumed with a bad clock, a wrong time server) would
make the next pass delete every cycle record, image and PLC idempotency key at once, and that
cannot be undone. :class:`ClockGuard` holds pruning by age (no I/O here: the pass gives it the
times and the newest cycle records) while either

- the wall time elapsed since the last pass disagrees with the monotonic time by more than
  :data:`STEP_MARGIN_S` (the clock was stepped), or
- at start (or while held), the wall clock is ahead of the newest cycle record by more than the shortest
  retention period; once held, the newest record stamped before the doubt counts (later ones carry the doubted clock).

Pruning by size needs no clock and goes on. The hold ends by itself when the clock agrees with the
records from before the doubt again (it was corrected), or once the clock is confirmed: the cell
recorded a cycle with it and it ran :data:`CONFIRM_S` without a step (a right clock after a plant
shutdown, or a clock set right by a step). A confirmed clock may still be wrong (set years ahead and
left so), so the records from before the doubt are then aged without the gap (:meth:`ClockGuard.cutoff`)
until the service has run a retention period past it: a record goes only once it is that old on any
clock that agrees with the monotonic one since the doubt began. This lasts while the service runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta

from cellctl.service.retention_figures import iso_utc

STEP_MARGIN_S = 600.0  # a wall-clock step smaller than this between two passes is not worth holding for
CONFIRM_S = 3600.0  # a clock that ran this long without a step, with a cycle recorded by it, is confirmed

Newest = tuple[int, datetime]  # a cycle record's id and creation time


@dataclass
class Gap:
    """``before``: the newest cycle record stamped before the clock was in doubt, and the earliest time a record
    made since may carry (a step back lowers it); ``since``: the wall time of the last doubt (a hold's start or a
    step): every record made before it is truly older than ``now - since``."""

    before: Newest
    since: datetime

    @property
    def length(self) -> timedelta:
        return max(self.since - self.before[1], timedelta(0))


class ClockGuard:
    """Reviews the wall clock at each pass; :attr:`held` says why pruning by age is held (None: it is not),
    :attr:`advice` what to do, :attr:`note` why the last hold ended."""

    def __init__(self, margin_s: float = STEP_MARGIN_S, confirm_s: float = CONFIRM_S) -> None:
        self.margin_s, self.confirm_s = margin_s, confirm_s
        self.held: str | None = None
        self.advice: str | None = None
        self.note: str | None = None
        self.trusted_id: int | None = None  # while held: the newest cycle stamped before the clock was in doubt
        self.gap: Gap | None = None  # records aged without a gap (after a confirmed doubt)
        self._last: tuple[datetime, float] | None = None  # wall and monotonic time of the last pass
        self._seen: Newest | None = None  # the newest cycle the last pass (with a trusted clock) saw
        self._doubt: tuple[float, int] = (0.0, 0)  # monotonic time and newest cycle id at the hold's start or last step

    def review(
        self, wall: datetime, mono: float, newest: Newest | None, trusted: Newest | None, periods: list[float]
    ) -> str | None:
        """Why pruning by age is held now, or None. ``newest``: the newest cycle record; ``trusted``: the
        newest of those up to :attr:`trusted_id` (``newest`` while not held); ``periods``: the finite
        retention periods in days."""
        prev, self._last = self._last, (wall, mono)
        step = None if prev is None else (wall - prev[0]).total_seconds() - (mono - prev[1])
        continuous = prev is not None and self.held is None  # the last pass trusted the clock
        shortest, nid = min(periods, default=None), (newest[0] if newest is not None else 0)
        if prev is not None and step is not None and abs(step) > self.margin_s:
            # Records made since the last pass carry the old clock (at least its reading then) or the new one.
            low = min(prev[0], wall - timedelta(seconds=mono - prev[1]))
            self._begin(wall, mono, nid, self._seen, low=low)
            self.held = f"the wall clock jumped by {step / 3600:+.1f} h since the last retention pass (against the monotonic clock)"
            self.advice = ("if the step was wrong, correct the clock, pruning resumes by itself; if it was right, "
                           f"pruning resumes {self._once}")  # fmt: skip
            return self.held
        if continuous:
            self._seen = newest
            if self.gap is not None and wall - timedelta(days=max(periods, default=0)) >= self.gap.since:
                self.gap = None  # no period reaches back past the gap any more
            return None
        ahead = None if trusted is None else wall - trusted[1]
        if ahead is None or shortest is None or ahead <= timedelta(days=shortest):
            if self.gap is not None and (shortest is None or wall - self.gap.before[1] <= timedelta(days=shortest)):
                self.gap = None  # the clock agrees with the records from before the doubt again
            self._release(newest, "the wall clock agrees with the records again")
            return None
        if self.held is not None and self._confirmed(wall, mono, newest):
            assert self.gap is not None
            self._release(newest, (
                f"cycle {nid} was recorded with the wall clock and it ran {self.confirm_s / 3600:g} h without a step; "
                f"records up to cycle {self.gap.before[0]} are aged without the {self.gap.length / timedelta(days=1):.1f} "
                f"days before {iso_utc(self.gap.since)} for one retention period from then"))  # fmt: skip
            return None
        if self.held is None:
            self._begin(wall, mono, nid, trusted, low=wall)
        t = trusted or (0, wall)
        later = "" if newest is None or newest[0] == t[0] else (
            f"; cycle {newest[0]}, the newest, of {iso_utc(newest[1])}, was stamped since with the clock in doubt")
        self.held = (f"the wall clock is {ahead / timedelta(days=1):.0f} days ahead of the newest cycle record "
                     f"(cycle {t[0]}) of {iso_utc(t[1])}, more than the shortest retention period ({shortest:g} days)"
                     f"{later}")  # fmt: skip
        self.advice = (f"if the clock is right (e.g. the cell stood idle that long), nothing to do: pruning resumes "
                       f"{self._once} (the records from before are then aged without those "
                       f"{ahead / timedelta(days=1):.0f} days for one retention period); if it is wrong, correct it")
        return self.held

    def cutoff(self, now: datetime, days: float) -> datetime:
        """Records created before this are older than ``days``: ``now - days``, less the gap while it is within ``days``."""
        cut = now - timedelta(days=days)
        return cut - self.gap.length if self.gap is not None and cut < self.gap.since else cut

    @property
    def _once(self) -> str:
        return f"by itself once the cell has recorded a cycle and run {self.confirm_s / 3600:g} h without a clock step"

    def _begin(self, wall: datetime, mono: float, newest_id: int, before: Newest | None, *, low: datetime) -> None:
        """The clock is in doubt from now: records after ``before`` may carry it (none of them stamped before
        ``low``); the gap runs from the earliest of those to now, and the confirmation starts again."""
        if self.trusted_id is None:
            self.trusted_id = before[0] if before is not None else 0
        first = self.gap.before if self.gap is not None else before
        if first is not None:
            self.gap = Gap((first[0], min(first[1], low)), wall)
        self._doubt = (mono, newest_id)

    def _confirmed(self, wall: datetime, mono: float, newest: Newest | None) -> bool:
        """A cycle was recorded since the doubt began (or the last step) and the clock ran confirm_s without a step."""
        t0, id0 = self._doubt
        return (self.gap is not None and newest is not None and newest[0] > id0 and mono - t0 >= self.confirm_s
                and newest[1] <= wall + timedelta(seconds=self.margin_s))  # fmt: skip

    def _release(self, newest: Newest | None, note: str) -> None:
        self.held, self.advice, self.trusted_id, self._seen, self.note = None, None, None, newest, note
