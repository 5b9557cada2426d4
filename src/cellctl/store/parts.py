"""Part traceability in the store: every install of a glass, or into a car body, with what people did.

A part install is a cycle record (:class:`~cellctl.store.records.CycleRecord`, with its steps and
image references) and the actions filed under that cycle: its audit-log entries (commands and the
state changes they caused, the closed loop's update; who, from where, when) and its alarms (raised,
acknowledged by whom, cleared). ``GET /parts`` and ``cellctl parts export`` are built on
:meth:`PartRows.part_installs`.

Filters combine (AND): the car body (``car_id``), the glass (``part_id``) and a time window.
The window is on the cycle's end stamp ``ended_at``, when the store closed its record: done or
failed, or for a cycle the service died in when the next start closed it (its ``interrupted_at``,
when it was cut off, may lie in a window an MES already exported while the cycle still ran). The
end stamp is the store's clock but never earlier than the latest one before it
(:func:`~cellctl.store.cycles.end_stamp`), so a wall clock stepped back (NTP) stamps no end into a
window already exported; ``finished_at`` keeps the wall clock's time.
``since`` is inclusive and ``until`` exclusive, so back-to-back windows ``[a, b)``, ``[b, c)``
list every ended install exactly once (what an MES export polls for) when ``b`` is the bound the
first one applied (:attr:`PartPage.until`): never later than the latest end stamp + 1 us (before
any end, than the store's clock, which the first end stamp then keeps as its floor), so every
later end falls at or after it, and never earlier than ``since`` (an empty window, the cell's
stamps standing behind ``since``). A window lists ended cycles only (a queued or running one has
no end yet, and its record is not final). Without a window, queued and running cycles are listed too.

Paging: ascending cycle id (the order the cell ran them). ``after_id`` is the previous page's
:attr:`PartPage.next_after`; a page that is not full is the last (``next_after`` None).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Any

from cellctl.domain import Alarm
from cellctl.store.alarms import ALARM_COLUMNS, alarm_from_row
from cellctl.store.audit import AUDIT_COLUMNS, audit_entry
from cellctl.store.connection import Database, dt, ts
from cellctl.store.cycles import CYCLE_COLUMNS, END_STEP, full_cycle, latest_end
from cellctl.store.records import AuditEntry, CycleRecord

MAX_PAGE = 1000
"""The most installs one :meth:`PartRows.part_installs` call returns."""

ENDED_AT = "ended_at"
"""The column the window filters on: the cycle's end stamp (NULL while it has not ended)."""


@dataclass(frozen=True)
class CycleActions:
    """What was done during a cycle: its audit entries (oldest first) and its alarms (by raise time)."""

    audit: tuple[AuditEntry, ...]
    alarms: tuple[Alarm, ...]


@dataclass(frozen=True)
class PartInstall:
    """One install: the cycle record with its steps and images, the actions filed under it, and its end stamp (UTC;
    None while it has not ended), the time the window is on."""

    record: CycleRecord
    actions: CycleActions
    ended_at: datetime | None = None


@dataclass(frozen=True)
class PartPage:
    """A page of installs, by ascending cycle id; ``next_after`` is the ``after_id`` of the next page (None: last page)."""

    installs: tuple[PartInstall, ...]
    next_after: int | None
    until: datetime | None = None  # the window's end as applied: see the module's doc


class PartRows(Database):
    """The part traceability queries of :class:`cellctl.store.db.CellStore`."""

    def part_installs(
        self,
        *,
        car_id: str | None = None,
        part_id: str | None = None,
        since: datetime | None = None,
        until: datetime | None = None,
        after_id: int | None = None,
        limit: int = 50,
    ) -> PartPage:
        """The installs matching every filter given (see the module's doc for the window and the paging).

        ``since``/``until`` must be timezone-aware; ``limit`` is 1 to :data:`MAX_PAGE`.
        """
        if not (1 <= limit <= MAX_PAGE):
            raise ValueError(f"limit must be in 1..{MAX_PAGE}, got {limit}")
        where: list[str] = []
        args: list[Any] = []
        for column, value in (("car_id", car_id), ("part_id", part_id)):
            if value is not None:
                where.append(f"{column} = ?")
                args.append(value)
        if since is not None and until is not None and until <= since:
            raise ValueError(f"until ({until.isoformat()}) must be later than since ({since.isoformat()})")
        if until is not None:  # an install ending later would otherwise miss this window and the next one
            until = self._applied_until(since, until)
        if since is not None:
            where.append(f"{ENDED_AT} >= ?")
            args.append(ts(since))
        if until is not None:
            where.append(f"{ENDED_AT} < ?")
            args.append(ts(until))
        if after_id is not None:
            where.append("id > ?")
            args.append(int(after_id))
        sql = f"SELECT {CYCLE_COLUMNS}, {ENDED_AT} FROM cycles"
        if where:
            sql += " WHERE " + " AND ".join(where)
        rows = self._conn.execute(f"{sql} ORDER BY id LIMIT ?", (*args, limit + 1)).fetchall()
        page = tuple(
            PartInstall(record, self.cycle_actions(record.id), dt(r[-1]))
            for r, record in ((r, full_cycle(self._conn, r[:-1])) for r in rows[:limit])
        )
        return PartPage(page, page[-1].record.id if len(rows) > limit else None, until)

    def _applied_until(self, since: datetime | None, until: datetime) -> datetime:
        """The window's end as applied: ``until``, but no later than the latest end stamp + 1 us (every later end falls
        at or after it, whatever the wall clock does), and no earlier than ``since`` (an empty window). Before any
        cycle ended, no later than the store's clock, kept as the floor of the first end stamp (written once)."""
        latest = latest_end(self._conn)
        if latest is not None:
            bound = min(until, latest + END_STEP)
        else:
            bound = min(until, self._clock())
            with self._tx() as c:  # an end already stamped meanwhile keeps its stamp (and was or will be listed)
                c.execute(
                    "UPDATE cycle_end_mark SET ended_at = ? WHERE id = 1 AND ended_at IS NULL", (ts(bound - END_STEP),)
                )
        return bound if since is None else max(since, bound)

    def cycle_actions(self, cycle_id: int) -> CycleActions:
        """The audit entries and alarms filed under ``cycle_id`` (both empty for an unknown cycle)."""
        audit = tuple(
            audit_entry(r)
            for r in self._conn.execute(f"SELECT {AUDIT_COLUMNS} FROM audit_log WHERE cycle_id = ? ORDER BY seq", (cycle_id,))
        )
        alarms = tuple(
            alarm_from_row(r)
            for r in self._conn.execute(
                f"SELECT {ALARM_COLUMNS} FROM alarms WHERE cycle_id = ? ORDER BY raised_at, uid", (cycle_id,)
            )
        )
        return CycleActions(audit, alarms)
