"""The bridge: the cell's events become outbox messages.

It follows the orchestrator's :class:`~cellctl.cell.events.EventHub`:

- ``state``: the retained ``state`` (PackML state, unit mode, cycle step);
- ``cycle`` done or failed: the results of every finished cycle above the store's high-water mark,
  in cycle order (``result`` and the retained ``result/last``), each queued in one transaction
  with the mark. At start the same catch-up queues what finished while no bridge ran (a restart
  between a cycle's end and its queueing, or cycles run with publication off), and interrupted
  cycles; the first start ever begins at the newest cycle (history is not published);
- ``alarm``: ``alarm/events`` when an alarm is raised, cleared or acknowledged (one message per
  change: :func:`alarm_events`), and the retained ``alarm/{code}``, emptied once no alarm of that
  code is listed (inactive and acknowledged);
- ``job`` done, and every ``CALIBRATION_POLL_S``: the retained ``calibration`` when its version changed.

After every connection's backlog (:meth:`EventBridge.snapshot`) it queues the retained values again,
``result/last`` included: the newest finished cycle at or below the high-water mark (the bound may
have dropped every ``result/last`` of an outage; a first start has none).

The hub drops a slow subscriber's oldest events; a gap in its sequence makes the bridge queue
the state, the alarms and the results again from their sources (and empty the ``alarm/{code}``
of every alarm that ended meanwhile), so nothing but an
``alarm/events`` entry can be lost that way (and that is logged).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from typing import Any, Protocol

from cellctl.cell.events import CellEvent, EventHub
from cellctl.cell.outcome import result_message
from cellctl.domain import Alarm
from cellctl.mqtt import payloads
from cellctl.mqtt.outbox import Outbox
from cellctl.mqtt.topics import CellTopics
from cellctl.store.outbox import RESULT_KIND, OutboxMessage
from cellctl.store.records import CycleState

log = logging.getLogger(__name__)

UNFINISHED = (CycleState.QUEUED, CycleState.RUNNING)  # cycles that have no result yet
CALIBRATION_POLL_S = 5.0  # a set written by `cellctl calibrate --dataset` outside the service is seen this late at most


class AlarmSource(Protocol):
    """What the bridge reads of the alarms (:class:`cellctl.cell.alarms.AlarmManager`)."""

    def current(self) -> list[Alarm]:
        """Alarms active or not yet acknowledged."""
        ...

    def get(self, uid: str) -> Alarm:
        """One alarm, listed or recently finished (KeyError when unknown)."""
        ...


class EventBridge:
    """Queues the cell's events as MQTT messages (see the module docstring)."""

    def __init__(
        self,
        outbox: Outbox,
        topics: CellTopics,
        events: EventHub,
        *,
        state_now: Callable[[], tuple[str, str, str]],
        alarms: AlarmSource,
        calibration_now: Callable[[], dict[str, Any]],
    ) -> None:
        self.outbox = outbox
        self.store = outbox.store
        self.topics = topics
        self.events = events
        self._state_now = state_now
        self.alarms = alarms
        self._calibration_now = calibration_now
        self._queue: asyncio.Queue[CellEvent] | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._last_event = 0
        self._alarm_seen: dict[str, tuple[bool, bool, int]] = {}  # uid -> (active, acknowledged, code) as last published
        self._calibration: tuple[Any, bool] | None = None  # (version, damaged) as last queued
        self._results = asyncio.Lock()  # a result/last of the snapshot never supersedes a newer one of catch_up

    # -- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
        """Catch up (results, alarms left set on the broker), then follow the hub."""
        self._queue = self.events.subscribe()
        await self.outbox.load()
        await self.store.outbox_start_results()
        await self.catch_up()
        await self._clear_stale_alarms()
        await self._check_calibration()
        for a in self.alarms.current():
            self._alarm_seen[a.uid] = (a.active, a.acknowledged, int(a.code))
        self._tasks = [
            asyncio.create_task(self._follow(self._queue), name="mqtt-bridge"),
            asyncio.create_task(self._poll_calibration(), name="mqtt-calibration"),
        ]

    async def stop(self) -> None:
        """Queue what the hub still holds, then stop following it."""
        for t in self._tasks:
            t.cancel()
        for t in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
        self._tasks = []
        q, self._queue = self._queue, None
        if q is not None:
            self.events.unsubscribe(q)
            while not q.empty():
                with contextlib.suppress(Exception):  # logged inside; stopping must go on
                    await self._handle(q.get_nowait())

    async def snapshot(self) -> None:
        """Queue the retained state, alarms, calibration and result/last as they are now (after every connection's backlog)."""
        await self._put_state(*self._state_now())
        for a in self.alarms.current():
            await self.outbox.put([OutboxMessage(self.topics.alarm(a.code), payloads.alarm(a), "alarm", retain=True)])
        self._calibration = None
        await self._check_calibration()
        await self._put_result_last()

    # -- following the hub ----------------------------------------------------------------------

    async def _follow(self, q: asyncio.Queue[CellEvent]) -> None:
        while True:
            ev = await q.get()
            try:
                await self._handle(ev)
            except Exception:  # one bad event must not end publication; logged with its trace
                log.exception("MQTT bridge: event %s %r could not be queued", ev.kind, ev.data)

    async def _handle(self, ev: CellEvent) -> None:
        if self._last_event and ev.seq > self._last_event + 1:
            await self._resync(ev.seq - self._last_event - 1)
        self._last_event = ev.seq
        d = ev.data
        if ev.kind == "state":
            await self._put_state(d["state"], d["mode"], d["step"])
        elif ev.kind == "cycle" and d.get("state") in ("done", "failed"):
            await self.catch_up()
        elif ev.kind == "alarm":
            await self._on_alarm(d)
        elif ev.kind == "job" and d.get("state") == "done" and d.get("version_after") is not None:
            await self._check_calibration()

    async def _resync(self, missed: int) -> None:
        log.warning("MQTT bridge: missed %d cell events (it fell behind); queueing state, alarms and results afresh", missed)
        await self.catch_up()
        await self._put_state(*self._state_now())
        listed = {a.uid: a for a in self.alarms.current()}
        ended = {seen[2] for uid, seen in self._alarm_seen.items() if uid not in listed}
        self._alarm_seen = {uid: seen for uid, seen in self._alarm_seen.items() if uid in listed}
        for code in sorted(ended - {int(a.code) for a in listed.values()}):  # the others are published below
            await self.outbox.put([OutboxMessage(self.topics.alarm(code), None, "alarm", retain=True)])
        for a in listed.values():
            await self._publish_alarm(a, ())

    async def _put_state(self, state: str, mode: str, step: str) -> None:
        await self.outbox.put([OutboxMessage(self.topics.state, payloads.state(state, mode, step), "state", retain=True)])

    # -- results --------------------------------------------------------------------------------

    async def catch_up(self) -> int:
        """Queue the result of every finished cycle above the high-water mark, in order; returns how many."""
        async with self._results:
            return await self._catch_up()

    async def _catch_up(self) -> int:
        n = 0
        while ids := await self.store.outbox_result_backlog(limit=50):
            for cid in ids:
                msg = result_message(await self.store.cycle(cid))
                if msg is None:  # not finished after all (the backlog stops before those): try again later
                    return n
                done = await self.outbox.put(
                    [OutboxMessage(self.topics.result, payloads.result(msg), RESULT_KIND),
                     OutboxMessage(self.topics.result_last, payloads.result(msg), "result_last", retain=True)],
                    result_of_cycle=cid,
                )  # fmt: skip
                n += bool(done.seqs)
        return n

    async def _put_result_last(self) -> None:
        """Queue the retained ``result/last`` of the newest finished cycle at or below the high-water mark."""
        async with self._results:  # the mark read and this queued before any newer result's result/last
            hwm = (await self.store.outbox_counts()).result_hwm
            before = None if hwm is None else hwm + 1
            while page := await self.store.cycles(limit=50, before_id=before):
                for rec in page:
                    msg = None if rec.state in UNFINISHED else result_message(await self.store.cycle(rec.id))
                    if msg is not None:
                        body = payloads.result(msg)
                        await self.outbox.put([OutboxMessage(self.topics.result_last, body, "result_last", retain=True)])
                        return
                before = page[-1].id

    # -- alarms ---------------------------------------------------------------------------------

    async def _on_alarm(self, d: dict[str, Any]) -> None:
        uid = str(d["uid"])
        now = (bool(d["active"]), bool(d["acknowledged"]))
        seen = self._alarm_seen.get(uid)
        before = None if seen is None else seen[:2]
        if before == now:
            return  # a reaction or a repeat: nothing the plant sees changed
        try:
            alarm = self.alarms.get(uid)
        except KeyError:
            log.warning("MQTT bridge: alarm %s (%s) is no longer known to the alarm manager; not published", uid, d.get("code"))
            return
        await self._publish_alarm(alarm, alarm_events(before, now), state=now)

    async def _publish_alarm(self, a: Alarm, events: tuple[str, ...], *, state: tuple[bool, bool] | None = None) -> None:
        active, acked = state or (a.active, a.acknowledged)
        if events:
            await self.outbox.put([OutboxMessage(self.topics.alarm_events, payloads.alarm(a, event=e), "alarm_event") for e in events])
        listed = active or not acked
        if listed:
            self._alarm_seen[a.uid] = (active, acked, int(a.code))
            await self.outbox.put([OutboxMessage(self.topics.alarm(a.code), payloads.alarm(a), "alarm", retain=True)])
            return
        self._alarm_seen.pop(a.uid, None)
        other = next((o for o in self.alarms.current() if o.code == a.code and o.uid != a.uid), None)
        body = None if other is None else payloads.alarm(other)  # another of the same code still holds the topic
        await self.outbox.put([OutboxMessage(self.topics.alarm(a.code), body, "alarm", retain=True)])

    async def _clear_stale_alarms(self) -> None:
        """Empty the retained alarm topics of alarms that ended while the service was down."""
        codes = {int(a.code) for a in self.alarms.current()}
        for topic in await self.store.outbox_retained_topics():
            if self.topics.is_alarm(topic) and int(topic.rsplit("/", 1)[1]) not in codes:
                await self.outbox.put([OutboxMessage(topic, None, "alarm", retain=True)])

    # -- calibration ----------------------------------------------------------------------------

    async def _check_calibration(self) -> None:
        ref = await asyncio.to_thread(self._calibration_now)  # a stat (and a read when the set changed)
        key = (ref.get("version"), bool(ref.get("damaged", False)))
        if key != self._calibration:
            self._calibration = key
            await self.outbox.put([OutboxMessage(self.topics.calibration, payloads.calibration(ref), "calibration", retain=True)])

    async def _poll_calibration(self) -> None:
        while True:
            await asyncio.sleep(CALIBRATION_POLL_S)
            try:
                await self._check_calibration()
            except Exception:  # the next poll tries again; logged with its trace
                log.exception("MQTT bridge: the calibration version could not be read")


def alarm_events(before: tuple[bool, bool] | None, now: tuple[bool, bool]) -> tuple[str, ...]:
    """The ``alarm/events`` names of an alarm's change from ``before`` to ``now`` (each (active, acknowledged)).

    One event per flag that changed, in this order: ``raised`` (first seen), ``cleared`` (active went
    false), ``acknowledged`` (acknowledged went true). An acknowledgement that also clears a latched
    alarm gives both ``cleared`` and ``acknowledged``.
    """
    if before is None:
        return ("raised",)
    changes = (("cleared", before[0] and not now[0]), ("acknowledged", now[1] and not before[1]))
    events = tuple(name for name, changed in changes if changed)
    return events or ("cleared",)  # flags never go back; kept as the old name for any other change
