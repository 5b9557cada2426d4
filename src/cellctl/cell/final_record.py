"""A finished cycle's final record: written at once, or kept in memory and written again while the store refuses it.

A glass that was installed must never lose its outcome to a store fault (disk full, another process holding
the write lock past ``busy_timeout_s``, an I/O error). The outcome is then kept, behind whatever the store
refused before it (the cycle's steps, audit entries: :mod:`cellctl.cell.store_faults`), and logged as one JSON
line, alarm 1703 (Hold) stops production until it is written, and a retry every ``retry_s`` seconds writes it
once the store takes writes again; only then is the cycle's end published (REST, PLC, OPC UA read it from the
store) and the alarm cleared. A restart before that leaves the record ``running`` with its install marker: the
next start marks it interrupted, never installs it again, and the outcome is in the log.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Awaitable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.events import EventHub
from cellctl.cell.store_faults import ALARM_SOURCE, RETRY_S, STORE_FAULTS, KeptWrite, WriteBehind
from cellctl.store import AsyncCellStore

__all__ = ["ALARM_SOURCE", "RETRY_S", "STORE_FAULTS", "FinalRecord", "FinalRecords", "despite_store_fault"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FinalRecord:
    """A cycle's end as the store takes it: ``done`` (``complete_cycle``) or ``failed`` (``fail_cycle``) with its
    keyword arguments, and the ``cycle`` event published once it is written."""

    cycle_id: int
    state: str
    fields: dict[str, Any]
    event: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def done(cls, cycle_id: int, result: dict[str, Any], true_error: Any, *, part_ok: bool) -> FinalRecord:
        """An installed cycle's end: its result (and, in simulation, the true error)."""
        fields = {"result": result, "true_error": true_error}
        return cls(cycle_id, "done", fields, {"cycle_id": cycle_id, "state": "done", "part_ok": part_ok})

    @classmethod
    def failed(cls, cycle_id: int, reason: str, result: dict[str, Any], true_error: Any) -> FinalRecord:
        """A failed cycle's end: why, and its figures."""
        fields = {"error": reason, "result": result, "true_error": true_error}
        return cls(cycle_id, "failed", fields, {"cycle_id": cycle_id, "state": "failed", "error": reason})

    def as_json(self) -> str:
        """One line of JSON: what the record says, for the log (figures that are not JSON are given as text)."""
        body = {"cycle_id": self.cycle_id, "state": self.state, **self.fields}
        return json.dumps(body, sort_keys=True, default=str, separators=(",", ":"))


class FinalRecords:
    """Writes cycles' final records through the cell's :class:`~cellctl.cell.store_faults.WriteBehind` (``writes``):
    one the store refuses is kept, with what was kept before it, and written again, alarm 1703 meanwhile."""

    def __init__(self, store: AsyncCellStore, alarms: AlarmManager, events: EventHub, *, retry_s: float = RETRY_S) -> None:
        self.store = store
        self.events = events
        self.writes = WriteBehind(store, alarms, retry_s=retry_s)
        """Every store write of the cell that must not be lost: steps, audit entries, alarms, final records."""

    async def write(self, record: FinalRecord) -> bool:
        """Write ``record`` (after anything kept before it, e.g. its steps); on a store fault keep it, alarm, and retry.
        Its ``cycle`` event is published once it is written. True if written now."""
        self.writes.installing = None  # the cycle has ended: an alarm (a Hold) no longer cuts anything short
        write = self.store.complete_cycle if record.state == "done" else self.store.fail_cycle

        def written(kept: bool) -> None:
            self.events.publish("cycle", record.event)
            if kept:
                log.warning("cycle %d: its final record (%s) is written now", record.cycle_id, record.state)

        what = f"cycle {record.cycle_id} ({record.state}): its final record"
        call = partial(write, record.cycle_id, **record.fields)
        return await self.writes.write(KeptWrite(what, call, record.as_json(), record.cycle_id, written))

    async def stop(self) -> None:
        """Stop retrying after one last attempt; what is still unwritten is in the log (the next start marks the
        cycles it leaves running interrupted)."""
        await self.writes.stop()


async def despite_store_fault(write: Awaitable[object], what: str) -> None:
    """Await a store write whose loss must not stop what follows (an audit entry, a step's figures): a fault is logged."""
    try:
        await write
    except STORE_FAULTS:
        log.exception("%s could not be written to the store", what)
