"""Alarms: the alarm manager (raise, clear, acknowledge, react, first-out stop reason).

The manager applies the tables of :mod:`cellctl.cell.alarm_table` (fault class -> PackML command,
alarm code -> fault class, text, condition or event) and makes :class:`~cellctl.domain.Alarm`
records: the fields of PackML's alarm structure (``PackMLAlarmDataType``: ID, Value, Message,
Category, DateTime, AckDateTime, Trigger) plus severity, source and the reaction taken. The fault
class's integer is the PackML ``Category``.

Recovery interlock: while an alarm with a reaction is active, Reset, Start, Unhold and Unsuspend
are refused (``install()`` registers the guards) and entering Execute re-applies the strongest
pending reaction, so production never resumes over an unresolved fault. Clear (Aborted ->
Stopped) stays open so the operator can always leave Aborted.

The alarm records and enumerations (:mod:`cellctl.domain`) and the tables are re-exported here,
so ``from cellctl.cell.alarms import AlarmCode, AlarmManager`` gives a caller all it needs.
"""

from __future__ import annotations

import asyncio
import enum
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from datetime import datetime, timezone

from cellctl.cell.alarm_table import (
    ALARM_CATALOGUE,
    REACTIONS,
    RECOVERY_COMMANDS,
    STOP_REASON_RESET_COMMANDS,
    reaction_for,
)
from cellctl.cell.observers import Fanout
from cellctl.cell.packml import CommandRefused, PackMLMachine, next_state
from cellctl.domain import (
    Alarm,
    AlarmCode,
    FaultClass,
    MachineEvent,
    PackMLCommand,
    PackMLState,
    Severity,
)

# The records (cellctl.domain) and tables (cellctl.cell.alarm_table) are re-exported for the callers.
__all__ = [
    "ALARM_CATALOGUE",
    "REACTIONS",
    "RECOVERY_COMMANDS",
    "Alarm",
    "AlarmCode",
    "AlarmEvent",
    "AlarmEventKind",
    "AlarmManager",
    "FaultClass",
    "Severity",
    "UnknownAlarm",
]

C = PackMLCommand

_STRENGTH: Mapping[PackMLCommand, int] = {C.SUSPEND: 1, C.HOLD: 2, C.STOP: 3, C.ABORT: 4}
"""How strong a reaction is: entering Execute applies the strongest pending one."""

_STANDING_STOPS = frozenset({PackMLState.ABORTED, PackMLState.STOPPED})
"""States a fault cannot stop further: an alarm with a reaction raised there names the stop if nothing did."""


# --- Events --------------------------------------------------------------------------------------


class AlarmEventKind(enum.Enum):
    RAISED = "raised"
    REACTED = "reacted"
    CLEARED = "cleared"
    ACKNOWLEDGED = "acknowledged"


@dataclass(frozen=True)
class AlarmEvent:
    kind: AlarmEventKind
    alarm: Alarm
    at: datetime


class UnknownAlarm(KeyError):
    """No alarm with this uid (the API answers 404)."""

    def __init__(self, uid: str) -> None:
        super().__init__(uid)
        self.uid = uid

    def __str__(self) -> str:
        return f"no alarm with uid {self.uid!r}: list the current ones with GET /alarms"


def _utcnow() -> datetime:
    return datetime.now(timezone.utc)


# --- The manager ---------------------------------------------------------------------------------


class AlarmManager:
    """Raises, clears and acknowledges alarms; issues the reaction on the PackML machine.

    Args:
        machine: the cell's machine, or None (alarms are then only recorded).
        robot_moving: tells whether a robot motion is in progress now (for reactions that differ).
        clock: UTC wall clock.
        history: how many finished (inactive and acknowledged) alarms to keep in memory.
    """

    def __init__(
        self,
        machine: PackMLMachine | None = None,
        *,
        robot_moving: Callable[[], bool] = lambda: False,
        clock: Callable[[], datetime] = _utcnow,
        history: int = 200,
    ) -> None:
        self._machine = machine
        self._robot_moving = robot_moving
        self._clock = clock
        self._alarms: dict[str, Alarm] = {}
        self._history: deque[Alarm] = deque(maxlen=history)
        self._stop_reason: Alarm | None = None
        self._stop_reason_standing = False  # named while the cell already stood; the next reaction that moves it takes over
        self._events: Fanout[AlarmEvent] = Fanout("alarm")
        self._tasks: set[asyncio.Task[None]] = set()
        self._installed = False

    def install(self) -> None:
        """Hook into the machine: recovery guards, stop-reason release, reaction on entering Execute."""
        if self._machine is None or self._installed:
            return
        for cmd in RECOVERY_COMMANDS:
            self._machine.add_guard(cmd, self.recovery_guard)
        self._machine.subscribe(self._on_machine_event)
        self._installed = True

    # -- reading ------------------------------------------------------------------------------

    @property
    def stop_reason(self) -> Alarm | None:
        """The first-out alarm: the first whose reaction stopped production (in Aborted or Stopped, the first
        with a reaction raised there, until one's reaction moves the cell), kept until reset."""
        if self._stop_reason is None:
            return None
        return self._alarms.get(self._stop_reason.uid, self._stop_reason)

    def current(self) -> list[Alarm]:
        """Alarms that are active or unacknowledged, oldest first."""
        return sorted(self._alarms.values(), key=lambda a: a.raised_at)

    def active(self) -> list[Alarm]:
        return [a for a in self.current() if a.active]

    def recent(self) -> list[Alarm]:
        """Finished alarms still in memory, newest last."""
        return list(self._history)

    def get(self, uid: str) -> Alarm:
        if uid in self._alarms:
            return self._alarms[uid]
        for a in self._history:
            if a.uid == uid:
                return a
        raise UnknownAlarm(uid)

    def find_active(self, code: AlarmCode, source: str) -> Alarm | None:
        for a in self._alarms.values():
            if a.active and a.code == code and a.source == source:
                return a
        return None

    def interlocking(self) -> list[Alarm]:
        """Active alarms with a reaction, oldest first: they hold back the recovery commands (Reset, Start, Unhold,
        Unsuspend)."""
        return [a for a in self.active() if REACTIONS[a.category].when_still or REACTIONS[a.category].when_moving]

    def recovery_guard(self, state: PackMLState, command: PackMLCommand) -> str | None:
        """Machine guard: refuse a recovery command while an alarm with a reaction is active."""
        blocking = self.interlocking()
        if not blocking:
            return None
        first = blocking[0]
        how = "clear its cause" if first.condition else "acknowledge it"
        more = f" and {len(blocking) - 1} more" if len(blocking) > 1 else ""
        return f"{first.summary()} is active{more}: {how} first"

    def subscribe(self, callback: Callable[[AlarmEvent], object]) -> Callable[[], None]:
        """Call ``callback(event)`` on every raise, reaction, clear and acknowledge."""
        return self._events.subscribe(callback)

    def subscribe_queue(self, maxsize: int = 0) -> asyncio.Queue[AlarmEvent]:
        return self._events.subscribe_queue(maxsize)

    # -- changing -----------------------------------------------------------------------------

    async def raise_alarm(
        self,
        code: AlarmCode | int,
        *,
        source: str,
        detail: str = "",
        value: int = 0,
        cycle_id: int | None = None,
        robot_moving: bool | None = None,
    ) -> Alarm:
        """Raise an alarm and issue its reaction if the machine's state allows it now.

        A second raise of a condition or event that is still active (same code and source)
        returns the existing record unchanged. If the reaction is not possible in the current
        state (e.g. Hold while Idle) nothing is issued, and the alarm blocks recovery commands;
        entering Execute later applies it.
        """
        try:
            code = AlarmCode(code)
        except ValueError:
            raise ValueError(
                f"unknown alarm code {code!r}: add it to cellctl.domain.AlarmCode and "
                "cellctl.cell.alarm_table.ALARM_CATALOGUE"
            ) from None
        if not source:
            raise ValueError("source must name what raised the alarm (e.g. 'laser', 'plc', 'cycle')")
        existing = self.find_active(code, source)
        if existing is not None:
            return existing
        spec = ALARM_CATALOGUE[code]
        now = self._clock()
        alarm = Alarm(
            uid=uuid.uuid4().hex,
            code=code,
            value=int(value),
            message=f"{spec.text}: {detail}" if detail else spec.text,
            category=spec.fault_class,
            severity=REACTIONS[spec.fault_class].severity,
            source=source,
            raised_at=now,
            condition=spec.condition,
            cycle_id=cycle_id,
        )
        self._alarms[alarm.uid] = alarm
        self._events.publish(AlarmEvent(AlarmEventKind.RAISED, alarm, now))
        moving = self._robot_moving() if robot_moving is None else robot_moving
        await self._react(alarm.uid, reaction_for(alarm.category, robot_moving=moving))
        return self._alarms.get(alarm.uid, alarm)

    def clear(self, code: AlarmCode | int, *, source: str) -> Alarm | None:
        """The condition behind a condition alarm went away. Returns the record, or None if none
        was active. The record stays listed until acknowledged."""
        alarm = self.find_active(AlarmCode(code), source)
        if alarm is None:
            return None
        if not alarm.condition:
            raise ValueError(f"{alarm.summary()} is a latched event: acknowledge it instead of clearing it")
        now = self._clock()
        return self._update(alarm, AlarmEventKind.CLEARED, now, active=False, cleared_at=now)

    def acknowledge(self, uid: str, *, by: str) -> Alarm:
        """Acknowledge an alarm (a latched event alarm also goes inactive). Acknowledging twice
        keeps the first acknowledgement."""
        if not by:
            raise ValueError("by must name who acknowledges (user name or 'plc')")
        alarm = self.get(uid)
        if alarm.acknowledged:
            return alarm
        now = self._clock()
        changes: dict[str, object] = {"ack_at": now, "ack_by": by}
        if not alarm.condition and alarm.active:
            changes.update(active=False, cleared_at=now)
        return self._update(alarm, AlarmEventKind.ACKNOWLEDGED, now, **changes)

    def acknowledge_all(self, *, by: str) -> list[Alarm]:
        return [self.acknowledge(a.uid, by=by) for a in self.current() if not a.acknowledged]

    def restore(self, alarms: Iterable[Alarm]) -> list[Alarm]:
        """List the alarms a previous run left unacknowledged, inactive (this run raises its own for a condition that
        persists): no event, no reaction; they are acknowledged like any other. Returns those stored as active (a
        condition still present at the shutdown, its clearing unknown): the store should say they are not."""
        ended: list[Alarm] = []
        for a in alarms:
            if a.acknowledged or a.uid in self._alarms:
                continue
            self._alarms[a.uid] = replace(a, active=False)
            if a.active:
                ended.append(self._alarms[a.uid])
        return ended

    def reset_stop_reason(self) -> None:
        self._stop_reason, self._stop_reason_standing = None, False

    async def drain(self) -> None:
        """Wait for reactions scheduled from machine events (tests, shutdown)."""
        while self._tasks:
            await asyncio.gather(*list(self._tasks), return_exceptions=True)

    # -- internals ----------------------------------------------------------------------------

    def _update(self, alarm: Alarm, kind: AlarmEventKind, now: datetime, **changes: object) -> Alarm:
        new = replace(alarm, **changes)  # type: ignore[arg-type]
        if new.listed:
            self._alarms[new.uid] = new
        else:
            self._alarms.pop(new.uid, None)
            self._history.append(new)
        if self._stop_reason is not None and self._stop_reason.uid == new.uid:
            self._stop_reason = new
        self._events.publish(AlarmEvent(kind, new, now))
        return new

    async def _react(self, uid: str, command: PackMLCommand | None) -> None:
        m = self._machine
        if m is None or command is None:
            return
        if next_state(m.state, command) is None:
            self._name_standing_stop(uid, m.state)
            return
        alarm = self._alarms.get(uid)
        if alarm is None or not alarm.active:
            return
        try:
            await m.command(command, actor="system", source=f"alarm:{alarm.code.value}")
        except CommandRefused:
            return  # the state moved on between the check and the command
        if self._stop_reason is None or self._stop_reason_standing:  # a fault that moved the cell outranks a standing one
            self._stop_reason, self._stop_reason_standing = alarm, False
        self._update(self._alarms.get(uid, alarm), AlarmEventKind.REACTED, self._clock(), reaction=command)

    def _name_standing_stop(self, uid: str, state: PackMLState) -> None:
        """An alarm with a reaction while the cell already stands in Aborted or Stopped (its start state, say) with
        no stop reason becomes the first-out stop reason: the one fault that keeps it there, until a Reset."""
        alarm = self._alarms.get(uid)
        if self._stop_reason is None and state in _STANDING_STOPS and alarm is not None and alarm.active:
            self._stop_reason, self._stop_reason_standing = alarm, True

    def _on_machine_event(self, ev: MachineEvent) -> None:
        if ev.command in STOP_REASON_RESET_COMMANDS:
            self._stop_reason, self._stop_reason_standing = None, False
        if ev.state_after == PackMLState.EXECUTE and ev.state_changed:
            task = asyncio.get_running_loop().create_task(self._react_pending())
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

    async def _react_pending(self) -> None:
        moving = self._robot_moving()
        pending = [(reaction_for(a.category, robot_moving=moving), a) for a in self.active()]
        pending = [(c, a) for c, a in pending if c is not None]
        if pending:
            cmd, alarm = max(pending, key=lambda ca: _STRENGTH[ca[0]])  # type: ignore[index]
            await self._react(alarm.uid, cmd)
