"""Store writes kept while the store refuses them, written again in order once it takes writes.

What the cell has done must not be lost to a store fault (disk full, another process holding the write lock past
``busy_timeout_s``, an I/O error): a cycle's steps, images and final record, the audit entries of commands, alarm
reactions and acknowledgements, the alarm history. :class:`WriteBehind` tries a write at once. One the store refuses,
and every write after it while any is kept (their order is the order of events: the audit log's chain, a cycle's
steps before its end), is kept in memory and logged as one JSON line; alarm 1703 (Hold) stops production, and a retry
every ``retry_s`` seconds writes them in order. The alarm clears once all are written.

While a cycle that began its install measures its glass (:attr:`WriteBehind.installing`), the alarm waits for that
cycle's final record: a Hold then would cut the inspection short and lose the measurement of a glass that is in.
Before the install a refused write ends the cycle (:class:`WriteRefused`): no glass goes in without its marker.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import sqlite3
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from functools import partial
from typing import Any

from cellctl.cell.alarms import AlarmManager
from cellctl.domain import Alarm, AlarmCode, MachineEvent
from cellctl.store import AsyncCellStore

log = logging.getLogger(__name__)

STORE_FAULTS: tuple[type[BaseException], ...] = (sqlite3.Error,)
"""What a store write raises when the database cannot take it now (full disk, lock held, I/O error)."""

ALARM_SOURCE = "store"
RETRY_S = 3.0
"""Seconds between two attempts to write what the store refused."""


class WriteRefused(Exception):
    """A running cycle's record the store (or the image folder) refused before the install: the cycle ends there,
    alarm 1703 raised (the message says what was refused and why)."""


def as_json(body: Any) -> str:
    """One line of JSON for the log (what is not JSON is given as text)."""
    return json.dumps(body, sort_keys=True, default=str, separators=(",", ":"))


@dataclass(frozen=True)
class KeptWrite:
    """One store write: ``call()`` makes it (each call a new attempt), ``what`` names it in the log and the alarm,
    ``body`` is its JSON line; ``written(kept)`` runs once it is written (``kept``: after a refusal)."""

    what: str
    call: Callable[[], Awaitable[object]]
    body: str
    cycle_id: int | None = None
    written: Callable[[bool], None] | None = None


class WriteBehind:
    """Writes to the store in order; keeps what it refuses, alarm 1703 meanwhile, and writes it again every ``retry_s`` s.
    ``alarms`` None: no alarm (a recorder without a cell, in tests)."""

    def __init__(self, store: AsyncCellStore, alarms: AlarmManager | None, *, retry_s: float = RETRY_S) -> None:
        self.store = store
        self.alarms = alarms
        self.retry_s = retry_s
        self.installing: int | None = None
        """The cycle whose glass is in or going in, until its final record: no alarm (no Hold) before that record."""
        self._kept: deque[KeptWrite] = deque()
        self._fault: BaseException | None = None  # the store's latest refusal
        self._alarmed = False
        self._retry: asyncio.Task[None] | None = None
        self._order = asyncio.Lock()  # one write (or flush) at a time, in the order they came
        self._tasks: set[asyncio.Task[None]] = set()

    @property
    def kept(self) -> list[KeptWrite]:
        """The writes the store has not taken yet, oldest first."""
        return list(self._kept)

    async def write(self, item: KeptWrite) -> bool:
        """Write ``item`` (after any kept before it); on a store fault keep it, alarm and retry. True if written now."""
        async with self._order:  # the check, the attempt and the keeping as one: no write overtakes one before it
            behind = bool(self._kept)
            if not behind:
                try:
                    await item.call()
                except STORE_FAULTS as err:
                    self._fault = err
                    log.warning("%s: the store refused it: %s: %s", item.what, type(err).__name__, err)
                else:
                    if item.written is not None:
                        item.written(False)
                    if self._alarmed:  # nothing kept (the install marker's refusal): the store takes writes again
                        self._clear()
                    return True
            self._kept.append(item)
        how = "behind what the store refused before it" if behind else "until the store takes it"
        log.error("%s is kept in memory %s: %s", item.what, how, item.body)
        await self._alarm(item.what, item.cycle_id)  # outside the lock: its reaction's audit entry comes through here
        if self._retry is None or self._retry.done():
            self._retry = asyncio.create_task(self._retry_loop())
        return False

    async def audit(self, **entry: Any) -> bool:
        """An audit entry (the store's ``append_audit`` arguments), stamped now unless ``at`` is given."""
        entry.setdefault("at", datetime.now(timezone.utc))
        what = f"the audit entry {entry.get('action')}"
        return await self.write(KeptWrite(what, partial(self.store.append_audit, **entry), as_json(entry), entry.get("cycle_id")))

    async def machine_event(self, ev: MachineEvent, *, cycle_id: int | None) -> bool:
        """The audit entry of a PackML machine event (at the event's time)."""
        what = f"the audit entry of machine event {ev.seq} ({ev.kind.value}, {ev.state_before.name} -> {ev.state_after.name})"
        call = partial(self.store.append_machine_event, ev, cycle_id=cycle_id)
        return await self.write(KeptWrite(what, call, as_json(asdict(ev) | {"cycle_id": cycle_id}), cycle_id))

    async def alarm(self, alarm: Alarm) -> bool:
        """An alarm's record as it is now (raise, reaction, clear, acknowledgement)."""
        what = f"alarm {int(alarm.code)}'s record ({alarm.uid})"
        return await self.write(KeptWrite(what, partial(self.store.save_alarm, alarm), as_json(asdict(alarm)), alarm.cycle_id))

    async def refused(self, what: str, fault: BaseException, cycle_id: int | None) -> None:
        """A write that is not kept (the install marker: no install without it) was refused: alarm 1703 all the same,
        cleared by the next write the store takes with nothing kept."""
        self._fault = fault
        log.error("%s: refused: %s: %s", what, type(fault).__name__, fault)
        await self._alarm(what, cycle_id)

    def cycle_fault(self, cycle_id: int, err: Exception) -> tuple[str, int, AlarmCode | None]:
        """How a cycle that raised ``err`` outside its own handling ends: (reason, error code, alarm to raise). A store
        fault ends it with code 1703 (its alarm raised here, once), any other fault as a software fault (1501)."""
        if isinstance(err, WriteRefused):  # the recorder raised alarm 1703 already
            log.error("cycle %d: %s", cycle_id, err)
            return f"store fault: {err}", int(AlarmCode.RECORD_WRITE_FAILED), None
        if isinstance(err, STORE_FAULTS):
            log.error("cycle %d: the store refused a write: %s: %s", cycle_id, type(err).__name__, err)
            task = asyncio.ensure_future(self.refused(f"cycle {cycle_id}'s record", err, cycle_id))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
            return f"store fault: the store refused cycle {cycle_id}'s record: {type(err).__name__}: {err}", \
                int(AlarmCode.RECORD_WRITE_FAILED), None  # fmt: skip
        log.error("cycle %d failed", cycle_id, exc_info=err)
        return f"software fault: {type(err).__name__}: {err}", int(AlarmCode.TASK_FAILED), AlarmCode.TASK_FAILED

    async def flush(self) -> bool:
        """Write the kept writes in order; the alarm clears once all are written. True if none is left."""
        async with self._order:
            while self._kept:
                item = self._kept[0]
                try:
                    await item.call()
                except STORE_FAULTS as err:
                    self._fault = err
                    log.warning("%s: the store refused it again: %s: %s", item.what, type(err).__name__, err)
                    return False
                except Exception:  # noqa: BLE001 - not a store fault: retrying cannot help; its JSON is in the log
                    log.exception("%s cannot be written: %s", item.what, item.body)
                else:
                    log.warning("%s is written now", item.what)
                    if item.written is not None:
                        item.written(True)
                self._kept.popleft()
            self._clear()
            return True

    async def stop(self) -> None:
        """Stop retrying after one last attempt; what is still kept is in the log."""
        if self._retry is not None:
            self._retry.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._retry
            self._retry = None
        await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._kept and not await self.flush():
            log.error("not written at stop (see their JSON above; cycles left running are marked interrupted at the "
                      "next start): %s", "; ".join(i.what for i in self._kept))  # fmt: skip

    async def _retry_loop(self) -> None:
        while self._kept:
            await asyncio.sleep(self.retry_s)
            await asyncio.shield(self.flush())  # a stop waits for a pass under way: no write is made twice

    async def _alarm(self, what: str, cycle_id: int | None) -> None:
        if self._alarmed or self.alarms is None or self.installing is not None:
            return
        self._alarmed = True
        fault = self._fault
        detail = (
            f"{what} not written: {type(fault).__name__}: {fault}. It is kept in memory and in the log with what came "
            f"after it, and written again every {self.retry_s:g} s: free disk space for [store] path or end what holds "
            "the database; the alarm clears once all is written"
        )
        await self.alarms.raise_alarm(AlarmCode.RECORD_WRITE_FAILED, source=ALARM_SOURCE, detail=detail, cycle_id=cycle_id)

    def _clear(self) -> None:
        self._alarmed = False
        if self.alarms is not None:
            self.alarms.clear(AlarmCode.RECORD_WRITE_FAILED, source=ALARM_SOURCE)
