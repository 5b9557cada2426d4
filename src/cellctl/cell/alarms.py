"""Alarms: PackML alarm records, the fault-to-command reaction table, first-out stop reason, acknowledge.

Two tables are the single sources of truth here:

- :data:`REACTIONS`: fault class -> the PackML command the cell issues (cell_conventions.md 1.3):
  vision/measurement NOK or operator intervention -> Hold (internal, the operator fixes it);
  external conditions (no car, PLC not ready) -> Suspend (resumes when the condition clears);
  robot/controller fault, or the PLC heartbeat lost while the robot moves -> Abort.
- :data:`ALARM_CATALOGUE`: alarm code (PackML ``Alarm.ID``) -> fault class, text, and whether
  the alarm is a *condition* (active until its source clears it, e.g. a lost link) or an *event*
  (latched: active until acknowledged, e.g. a corner not found).

A record carries the fields of PackML's alarm structure (``PackMLAlarmDataType``: ID, Value,
Message, Category, DateTime, AckDateTime, Trigger) plus severity, source and the reaction taken.
The fault class's integer is the PackML ``Category``.

Recovery interlock: while an alarm with a reaction is active, Reset, Start, Unhold and Unsuspend
are refused (``install()`` registers the guards) and entering Execute re-applies the strongest
pending reaction, so production never resumes over an unresolved fault. Clear (Aborted ->
Stopped) stays open so the operator can always leave Aborted.

Regenerate the docs with ``python -m cellctl.cell.alarms -o docs/alarm_reactions.md``.
"""

from __future__ import annotations

import asyncio
import enum
import uuid
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from types import MappingProxyType

from cellctl.cell.observers import Fanout
from cellctl.cell.packml import CommandRefused, MachineEvent, PackMLMachine, next_state
from cellctl.cell.tags import PackMLCommand, PackMLState
from cellctl.markdown_doc import markdown_doc_main

C = PackMLCommand


class FaultClass(enum.IntEnum):
    """What kind of fault; the value is the PackML alarm ``Category``."""

    MEASUREMENT_NOK = 1
    OPERATOR_INTERVENTION = 2
    SENSOR_LOST = 3
    EXTERNAL_CONDITION = 4
    PLC_HEARTBEAT_LOST = 5
    ROBOT_FAULT = 6
    SOFTWARE_FAULT = 7
    WARNING = 8


class Severity(enum.IntEnum):
    WARNING = 1  # shown and logged, no state change
    ERROR = 2  # production pauses (Hold or Suspend)
    CRITICAL = 3  # the cell aborts (or may, e.g. heartbeat lost while moving)


@dataclass(frozen=True)
class Reaction:
    """The command for a fault class, with the robot standing still or moving."""

    when_still: PackMLCommand | None
    when_moving: PackMLCommand | None
    severity: Severity
    why: str

    def command(self, robot_moving: bool) -> PackMLCommand | None:
        return self.when_moving if robot_moving else self.when_still


REACTIONS: Mapping[FaultClass, Reaction] = MappingProxyType(
    {
        FaultClass.MEASUREMENT_NOK: Reaction(
            C.HOLD, C.HOLD, Severity.ERROR, "vision or measurement NOK: internal, the operator fixes it"
        ),
        FaultClass.OPERATOR_INTERVENTION: Reaction(
            C.HOLD, C.HOLD, Severity.ERROR, "needs an operator decision: internal, the operator fixes it"
        ),
        FaultClass.SENSOR_LOST: Reaction(
            C.HOLD, C.HOLD, Severity.ERROR, "laser or camera link lost: the cell cannot measure until it is back"
        ),
        FaultClass.EXTERNAL_CONDITION: Reaction(
            C.SUSPEND, C.SUSPEND, Severity.ERROR, "no car in position, PLC not ready: external, resumes when it clears"
        ),
        FaultClass.PLC_HEARTBEAT_LOST: Reaction(
            C.HOLD, C.ABORT, Severity.CRITICAL, "line PLC silent: Hold if the robot stands still, Abort if it moves"
        ),
        FaultClass.ROBOT_FAULT: Reaction(
            C.ABORT, C.ABORT, Severity.CRITICAL, "robot or controller fault, or its link lost"
        ),
        FaultClass.SOFTWARE_FAULT: Reaction(
            C.ABORT, C.ABORT, Severity.CRITICAL, "a supervised task of the cell died"
        ),
        FaultClass.WARNING: Reaction(None, None, Severity.WARNING, "shown and logged; no state change"),
    }
)

_STRENGTH: Mapping[PackMLCommand, int] = {C.SUSPEND: 1, C.HOLD: 2, C.STOP: 3, C.ABORT: 4}


class AlarmCode(enum.IntEnum):
    """PackML ``Alarm.ID`` values of this cell (the thousands group the fault family)."""

    LASER_LOST = 1101
    CAMERA_LOST = 1102
    ROBOT_LOST = 1103
    LASER_READ_FAILED = 1104
    CAMERA_GRAB_FAILED = 1105
    PLC_HEARTBEAT_LOST = 1201
    PLC_NOT_READY = 1202
    NO_CAR_IN_POSITION = 1203
    ALIGNMENT_FAILED = 1301
    CORNER_NOT_FOUND = 1302
    RESIDUAL_OVER_LIMIT = 1303
    CORRECTION_LIMIT_EXCEEDED = 1304
    CALIBRATION_INVALID = 1305
    CYCLE_INTERRUPTED = 1306
    CALIBRATION_DRIFT = 1307
    CALIBRATION_CHECK_DUE = 1308
    CYCLE_STOPPED = 1309
    NOT_IN_EXECUTE = 1310
    ROBOT_FAULT = 1401
    TASK_FAILED = 1501
    DEVICE_SLOW = 1601
    DISK_SPACE_LOW = 1701
    DISK_SPACE_CRITICAL = 1702


@dataclass(frozen=True)
class AlarmSpec:
    fault_class: FaultClass
    text: str
    condition: bool  # True: active until cleared by its source; False: latched until acknowledged


ALARM_CATALOGUE: Mapping[AlarmCode, AlarmSpec] = MappingProxyType(
    {
        AlarmCode.LASER_LOST: AlarmSpec(FaultClass.SENSOR_LOST, "Laser sensor link lost", True),
        AlarmCode.CAMERA_LOST: AlarmSpec(FaultClass.SENSOR_LOST, "Camera link lost", True),
        AlarmCode.ROBOT_LOST: AlarmSpec(FaultClass.ROBOT_FAULT, "Robot controller link lost", True),
        # What a cycle saw fail (an event: acknowledge it); the link itself is the watchdog's 1101/1102.
        AlarmCode.LASER_READ_FAILED: AlarmSpec(FaultClass.SENSOR_LOST, "A laser reading failed during the cycle", False),
        AlarmCode.CAMERA_GRAB_FAILED: AlarmSpec(FaultClass.SENSOR_LOST, "A camera grab failed during the cycle", False),
        AlarmCode.PLC_HEARTBEAT_LOST: AlarmSpec(FaultClass.PLC_HEARTBEAT_LOST, "Line PLC heartbeat lost", True),
        AlarmCode.PLC_NOT_READY: AlarmSpec(FaultClass.EXTERNAL_CONDITION, "Line PLC not ready", True),
        AlarmCode.NO_CAR_IN_POSITION: AlarmSpec(FaultClass.EXTERNAL_CONDITION, "No car body in position", True),
        AlarmCode.ALIGNMENT_FAILED: AlarmSpec(FaultClass.MEASUREMENT_NOK, "Laser alignment failed", False),
        AlarmCode.CORNER_NOT_FOUND: AlarmSpec(FaultClass.MEASUREMENT_NOK, "Opening corner not found in the image", False),
        AlarmCode.RESIDUAL_OVER_LIMIT: AlarmSpec(
            FaultClass.MEASUREMENT_NOK, "Verification shot residual above the threshold", False
        ),
        AlarmCode.CORRECTION_LIMIT_EXCEEDED: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION, "Correction larger than the configured limit", False
        ),
        AlarmCode.CALIBRATION_INVALID: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION, "Calibration set incomplete, invalid or out of date", False
        ),
        AlarmCode.CYCLE_INTERRUPTED: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION, "A cycle was interrupted by a restart: inspect the part", False
        ),
        AlarmCode.CALIBRATION_DRIFT: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION, "Calibration check: camera or laser moved beyond the limit, recalibrate", False
        ),
        AlarmCode.CYCLE_STOPPED: AlarmSpec(
            FaultClass.WARNING, "Cycle stopped by a PackML command (the code a stopped cycle reports; never raised)", False
        ),
        AlarmCode.NOT_IN_EXECUTE: AlarmSpec(
            FaultClass.WARNING, "Cycle refused: the cell is not in Execute (the code of that refusal; never raised)", False
        ),
        AlarmCode.CALIBRATION_CHECK_DUE: AlarmSpec(
            FaultClass.WARNING, "Calibration check due: run `cellctl calibrate verify`", True
        ),
        AlarmCode.ROBOT_FAULT: AlarmSpec(FaultClass.ROBOT_FAULT, "Robot refused or interrupted a motion", False),
        AlarmCode.TASK_FAILED: AlarmSpec(FaultClass.SOFTWARE_FAULT, "A cell task failed", False),
        AlarmCode.DEVICE_SLOW: AlarmSpec(FaultClass.WARNING, "Device missed a watchdog ping", True),
        # The store's disk ([store.retention] disk_warn_free_gb / disk_stop_free_gb): a warning first, then
        # a Hold so production stops while records and images can still be written; cleared when space is back.
        AlarmCode.DISK_SPACE_LOW: AlarmSpec(
            FaultClass.WARNING, "Disk space low for the store and images: free space or lower the retention", True
        ),
        AlarmCode.DISK_SPACE_CRITICAL: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION,
            "Disk almost full: production held before the store's writes fail; free space, then Unhold",
            True,
        ),
    }
)

RECOVERY_COMMANDS: frozenset[PackMLCommand] = frozenset({C.RESET, C.START, C.UNHOLD, C.UNSUSPEND})
"""Refused while an alarm with a reaction is active."""

STOP_REASON_RESET_COMMANDS: frozenset[PackMLCommand] = frozenset({C.RESET, C.UNHOLD, C.UNSUSPEND})
"""Accepting one of these ends the stop, so the first-out stop reason is released."""


def reaction_for(fault_class: FaultClass, *, robot_moving: bool) -> PackMLCommand | None:
    """The PackML command :data:`REACTIONS` prescribes."""
    return REACTIONS[fault_class].command(robot_moving)


# --- Records and events --------------------------------------------------------------------------


@dataclass(frozen=True)
class Alarm:
    """One alarm occurrence (PackML ``PackMLAlarmDataType`` plus what the cell needs).

    Attributes:
        uid: unique id of this occurrence (the store's key, the API's ``/alarms/{uid}``).
        code: PackML ``ID`` (an :class:`AlarmCode`).
        value: PackML ``Value``, a sub-code (e.g. the device's own error code), 0 if none.
        message: PackML ``Message``: the catalogue text and the detail.
        category: PackML ``Category``: the fault class.
        severity: from :data:`REACTIONS`.
        source: what raised it in the cell's words (``laser``, ``plc``, ``cycle``...).
        raised_at: PackML ``DateTime`` (UTC).
        ack_at / ack_by: PackML ``AckDateTime`` and who acknowledged.
        active: PackML ``Trigger``.
        condition: True for a condition alarm (cleared by its source), False for a latched event.
        cleared_at: when it went inactive.
        reaction: the command the cell issued for it, None if none was (needed).
        cycle_id: the cycle it happened in, if any.
    """

    uid: str
    code: AlarmCode
    value: int
    message: str
    category: FaultClass
    severity: Severity
    source: str
    raised_at: datetime
    active: bool = True
    condition: bool = True
    ack_at: datetime | None = None
    ack_by: str | None = None
    cleared_at: datetime | None = None
    reaction: PackMLCommand | None = None
    cycle_id: int | None = None

    @property
    def acknowledged(self) -> bool:
        return self.ack_at is not None

    @property
    def listed(self) -> bool:
        """Shown among the current alarms: active, or gone but not yet acknowledged."""
        return self.active or not self.acknowledged

    def summary(self) -> str:
        return f"alarm {self.code.value} ({self.message}) from {self.source}"


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
        """The first-out alarm: the first whose reaction stopped production, kept until reset."""
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

    def recovery_guard(self, state: PackMLState, command: PackMLCommand) -> str | None:
        """Machine guard: refuse a recovery command while an alarm with a reaction is active."""
        blocking = [a for a in self.active() if REACTIONS[a.category].when_still or REACTIONS[a.category].when_moving]
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
            raise ValueError(f"unknown alarm code {code!r}: add it to cellctl.cell.alarms.ALARM_CATALOGUE") from None
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

    def reset_stop_reason(self) -> None:
        self._stop_reason = None

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
        if m is None or command is None or next_state(m.state, command) is None:
            return
        alarm = self._alarms.get(uid)
        if alarm is None or not alarm.active:
            return
        try:
            await m.command(command, actor="system", source=f"alarm:{alarm.code.value}")
        except CommandRefused:
            return  # the state moved on between the check and the command
        if self._stop_reason is None:
            self._stop_reason = alarm
        self._update(self._alarms.get(uid, alarm), AlarmEventKind.REACTED, self._clock(), reaction=command)

    def _on_machine_event(self, ev: MachineEvent) -> None:
        if ev.command in STOP_REASON_RESET_COMMANDS:
            self._stop_reason = None
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


# --- Documentation -------------------------------------------------------------------------------


def _cmd(c: PackMLCommand | None) -> str:
    return "-" if c is None else c.name.title()


def render_markdown() -> str:
    """The reaction table and the alarm catalogue as Markdown (docs/alarm_reactions.md)."""
    lines = [
        "# Alarm reactions",
        "",
        "Generated from `cellctl.cell.alarms.REACTIONS` and `ALARM_CATALOGUE` by "
        "`python -m cellctl.cell.alarms -o docs/alarm_reactions.md`; do not edit by hand.",
        "",
        "## Fault class -> PackML command",
        "",
        "| Category | Fault class | Robot still | Robot moving | Severity | Why |",
        "|---|---|---|---|---|---|",
    ]
    for fc, r in REACTIONS.items():
        lines.append(
            f"| {fc.value} | {fc.name.lower()} | {_cmd(r.when_still)} | {_cmd(r.when_moving)} | "
            f"{r.severity.name.lower()} | {r.why} |"
        )
    lines += [
        "",
        "A reaction the current state does not accept (e.g. Hold in Idle) is not issued; the alarm then",
        "blocks " + ", ".join(sorted(c.name.title() for c in RECOVERY_COMMANDS)) + " while it is active,",
        "and entering Execute applies the strongest pending reaction. The first alarm whose reaction",
        "stopped production is the first-out stop reason until "
        + ", ".join(sorted(c.name.title() for c in STOP_REASON_RESET_COMMANDS))
        + " is accepted.",
        "",
        "## Alarm catalogue",
        "",
        "| ID | Name | Fault class | Kind | Text |",
        "|---|---|---|---|---|",
    ]
    for code, spec in ALARM_CATALOGUE.items():
        kind = "condition (until cleared)" if spec.condition else "event (until acknowledged)"
        lines.append(f"| {code.value} | {code.name.lower()} | {spec.fault_class.name.lower()} | {kind} | {spec.text} |")
    lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    return markdown_doc_main(argv, prog="python -m cellctl.cell.alarms", description=__doc__.splitlines()[0], render=render_markdown)


if __name__ == "__main__":
    raise SystemExit(main())
