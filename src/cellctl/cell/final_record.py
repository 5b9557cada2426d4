"""A finished cycle's final record: written at once, or kept in memory and written again while the store refuses it.

A glass that was installed must never lose its outcome to a store fault (disk full, another process holding
the write lock past ``busy_timeout_s``, an I/O error). The outcome is then kept here and logged as one JSON
line, alarm 1703 (Hold) stops production until it is written, and a retry every ``retry_s`` seconds writes it
once the store takes writes again; only then is the cycle's end published (REST, PLC, OPC UA read it from the
store) and the alarm cleared. A restart before that leaves the record ``running`` with its install marker: the
next start marks it interrupted, never installs it again, and the outcome is in the log.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import sqlite3
from collections.abc import Awaitable
from dataclasses import dataclass, field
from typing import Any

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.events import EventHub
from cellctl.domain import AlarmCode
from cellctl.store import AsyncCellStore

log = logging.getLogger(__name__)

STORE_FAULTS: tuple[type[BaseException], ...] = (sqlite3.Error,)
"""What a store write raises when the database cannot take it now (full disk, lock held, I/O error)."""

ALARM_SOURCE = "store"
RETRY_S = 3.0
"""Seconds between two attempts to write the records the store refused."""


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
    """Writes cycles' final records; keeps those the store refuses and writes them again, alarm 1703 meanwhile."""

    def __init__(self, store: AsyncCellStore, alarms: AlarmManager, events: EventHub, *, retry_s: float = RETRY_S) -> None:
        self.store = store
        self.alarms = alarms
        self.events = events
        self.retry_s = retry_s
        self._unwritten: dict[int, FinalRecord] = {}
        self._retry: asyncio.Task[None] | None = None

    @property
    def unwritten(self) -> list[int]:
        """The cycles whose final record the store has not taken yet, oldest first."""
        return list(self._unwritten)

    async def write(self, record: FinalRecord) -> bool:
        """Write ``record`` (after any kept before it); on a store fault keep it, alarm, and retry. True if written."""
        first = not self._unwritten
        fault = await self._try(record) if first else None
        if first and fault is None:
            return True
        self._unwritten[record.cycle_id] = record
        log.error("cycle %d: its final record is kept in memory until the store takes it: %s", record.cycle_id, record.as_json())
        if fault is not None:
            await self._alarm(record, fault)
        if self._retry is None or self._retry.done():
            self._retry = asyncio.create_task(self._retry_loop())
        return False

    async def flush(self) -> bool:
        """Write the kept records in order; the alarm clears once all are written. True if none is left."""
        for cycle_id, record in list(self._unwritten.items()):
            try:
                fault = await self._try(record)
            except Exception:  # noqa: BLE001 - not a store fault: retrying cannot help; its JSON is in the log
                log.exception("cycle %d: its final record cannot be written: %s", cycle_id, record.as_json())
                fault = None
            if fault is not None:
                return False
            del self._unwritten[cycle_id]
        if self._unwritten:  # one came in meanwhile: the next pass writes it
            return False
        self.alarms.clear(AlarmCode.RECORD_WRITE_FAILED, source=ALARM_SOURCE)
        return True

    async def stop(self) -> None:
        """Stop retrying after one last attempt; what is still unwritten is in the log (the next start marks it interrupted)."""
        if self._retry is not None:
            self._retry.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._retry
            self._retry = None
        if self._unwritten and not await self.flush():
            log.error("cycles %s: final records not written at stop (see their JSON above); the next start marks them "
                      "interrupted", self.unwritten)  # fmt: skip

    async def _retry_loop(self) -> None:
        while self._unwritten:
            await asyncio.sleep(self.retry_s)
            await self.flush()

    async def _try(self, record: FinalRecord) -> BaseException | None:
        """One attempt: None once written (and its end published), else the store's fault."""
        write = self.store.complete_cycle if record.state == "done" else self.store.fail_cycle
        try:
            await write(record.cycle_id, **record.fields)
        except STORE_FAULTS as err:
            log.warning("cycle %d: the store refused its final record: %s: %s", record.cycle_id, type(err).__name__, err)
            return err
        self.events.publish("cycle", record.event)
        if record.cycle_id in self._unwritten:
            log.warning("cycle %d: its final record (%s) is written now", record.cycle_id, record.state)
        return None

    async def _alarm(self, record: FinalRecord, fault: BaseException) -> None:
        detail = (
            f"cycle {record.cycle_id} ({record.state}) not recorded: {type(fault).__name__}: {fault}. Its outcome is kept "
            f"in memory and in the log and written again every {self.retry_s:g} s: free disk space for [store] path or end "
            "what holds the database; the alarm clears once it is written"
        )
        await self.alarms.raise_alarm(
            AlarmCode.RECORD_WRITE_FAILED, source=ALARM_SOURCE, detail=detail, cycle_id=record.cycle_id
        )


async def despite_store_fault(write: Awaitable[object], what: str) -> None:
    """Await a store write whose loss must not stop what follows (an audit entry, a step's figures): a fault is logged."""
    try:
        await write
    except STORE_FAULTS:
        log.exception("%s could not be written to the store", what)
