"""Every alarm's text names its fix: what the operator checks, then the PackML commands that bring the cell back.

Two rules over the whole catalogue:

- each text, after its symptom (up to the first ": "), tells the operator to do something: it contains one of
  :data:`ACTIONS`;
- the text of each alarm with a reaction is followed literally on a PackML machine with the alarm manager's
  interlocks: the alarm raised where it is raised (in Execute, with the robot still and moving), its source
  cleared for a condition ("once it is back"), then the words "acknowledge" and the PackML commands (Clear,
  Reset, Start, Stop, Unhold, Unsuspend) in the order the text names them. Each command must be accepted (not
  refused as blocked by the alarm, nor invalid in the state), and the cell must end in Execute. Only the PLC
  heartbeat alarm, whose reaction is a Hold or an Abort, may name two ways back ("Unhold, or after an Abort ...
  Clear, Reset, Start"): one contiguous run of them must do it.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Callable
from datetime import datetime, timedelta, timezone

import pytest

from cellctl.cell.alarm_table import ALARM_CATALOGUE, REACTIONS
from cellctl.cell.alarms import AlarmManager
from cellctl.cell.packml import ACTING_STATES, CommandBlocked, CommandRefused, PackMLMachine
from cellctl.domain import AlarmCode, FaultClass, PackMLCommand, PackMLState

S = PackMLState
C = PackMLCommand

ACTIONS = ("check", "inspect", "rework", "recalibrate", "redo", "run", "free", "lower", "teach", "see", "leave",
           "bring", "acknowledge")  # fmt: skip
"""What an operator is told to do, as the texts say it."""

_STEP = re.compile(r"\b(acknowledge|Clear|Reset|Start|Stop|Unhold|Unsuspend)\b")

RAISED_IN: dict[AlarmCode, S] = {
    AlarmCode.CYCLE_INTERRUPTED: S.ABORTED,  # when the service starts (orchestrator.start), before anything runs
    AlarmCode.CALIBRATION_DRIFT: S.STOPPED,  # by the verify job, which runs in Stopped or Idle
}
"""Alarms raised outside Execute: there their reaction is pending, and the text must unblock the cell."""

WITH_REACTION = [code for code, spec in ALARM_CATALOGUE.items() if REACTIONS[spec.fault_class].when_still is not None
                 or REACTIONS[spec.fault_class].when_moving is not None]  # fmt: skip


def ticking_clock() -> Callable[[], datetime]:
    t0 = datetime(2026, 11, 22, 8, 0, tzinfo=timezone.utc)
    counter = itertools.count()
    return lambda: t0 + timedelta(seconds=next(counter))


async def settle(m: PackMLMachine) -> None:
    while m.state in ACTING_STATES:
        await m.state_complete()


async def machine_in(state: S) -> PackMLMachine:
    m = PackMLMachine(clock=ticking_clock())  # starts in Aborted
    for cmd in (C.CLEAR, C.RESET, C.START):
        if m.state == state:
            break
        await m.command(cmd, actor="test", source="pytest")
        await settle(m)
    assert m.state == state
    return m


def remedy(text: str) -> str:
    """What the text says after its symptom."""
    return text.split(": ", 1)[1] if ": " in text else ""


@pytest.mark.parametrize("code", list(AlarmCode), ids=lambda c: c.name)
def test_every_alarm_text_tells_the_operator_what_to_do(code: AlarmCode) -> None:
    text = ALARM_CATALOGUE[code].text
    said = remedy(text).lower()
    assert any(re.search(rf"\b{verb}\b", said) for verb in ACTIONS), f"{code.value} names no fix: {text!r}"
    assert len(text) <= 240, f"{code.value}: keep it short ({len(text)} characters)"


@pytest.mark.parametrize("moving", [False, True], ids=["still", "moving"])
@pytest.mark.parametrize("code", WITH_REACTION, ids=lambda c: c.name)
async def test_following_the_text_brings_the_cell_back(code: AlarmCode, moving: bool) -> None:
    spec = ALARM_CATALOGUE[code]
    where = RAISED_IN.get(code, S.EXECUTE)
    m = await machine_in(where)
    am = AlarmManager(m, robot_moving=lambda: moving, clock=ticking_clock())
    am.install()
    alarm = await am.raise_alarm(code, source="unit", detail="what the source said")
    await settle(m)
    reaction = REACTIONS[spec.fault_class].command(moving)
    if where == S.EXECUTE:
        assert alarm.reaction == reaction and m.state != S.EXECUTE  # production stopped: the text must restart it
    if spec.condition:
        am.clear(code, source="unit")  # "once it is back"
    steps = _STEP.findall(spec.text)
    commands = [C[s.upper()] for s in steps if s != "acknowledge"]
    if not spec.condition:
        assert "acknowledge" in steps, f"{code.value} is an event: its text must say acknowledge: {spec.text!r}"
    two_ways = spec.fault_class is FaultClass.PLC_HEARTBEAT_LOST
    runs = [commands[i:j] for i in range(len(commands)) for j in range(i + 1, len(commands) + 1)] if two_ways \
        else [commands]  # fmt: skip
    state_after_reaction = m.state
    for step in steps:  # the acknowledgement where the text puts it, commands as far as the first refusal
        if step == "acknowledge":
            am.acknowledge(alarm.uid, by="operator")
        elif not two_ways:
            try:
                await m.command(C[step.upper()], actor="operator", source="hmi")
            except CommandBlocked as err:
                pytest.fail(f"{code.value}: the text's {step} is refused while the alarm blocks it: {err}")
            except CommandRefused as err:
                pytest.fail(f"{code.value}: the text's {step} is not a command of {m.state.name}: {err}")
            await settle(m)
    if where == S.STOPPED:  # no production stopped here: the text must leave nothing blocked for the next Start
        assert am.recovery_guard(m.state, C.RESET) is None, spec.text
        return
    if not two_ways:
        assert m.state == S.EXECUTE, f"{code.value}: following {spec.text!r} leaves the cell in {m.state.name}"
        return
    for run in runs:  # the PLC heartbeat alarm: one of the ways it names does it, from where its reaction left it
        trial = PackMLMachine(clock=ticking_clock(), initial_state=S.ABORTED)
        await _drive_to(trial, state_after_reaction)
        try:
            for cmd in run:
                await trial.command(cmd, actor="operator", source="hmi")
                await settle(trial)
        except CommandRefused:
            continue
        if trial.state == S.EXECUTE:
            return
    pytest.fail(f"{code.value}: no way named in {spec.text!r} leads from {state_after_reaction.name} to Execute")


async def _drive_to(m: PackMLMachine, state: S) -> None:
    """Aborted -> Execute, then the reaction that left the other machine in ``state`` (Held or Aborted)."""
    if state == S.ABORTED:
        return
    for cmd in (C.CLEAR, C.RESET, C.START, {S.HELD: C.HOLD, S.SUSPENDED: C.SUSPEND}[state]):
        await m.command(cmd, actor="test", source="pytest")
        await settle(m)
    assert m.state == state


def test_the_robot_and_device_link_alarms_name_the_controller_the_robot_and_the_glass() -> None:
    """Finding: 1103 and 1401 said only the symptom; a robot fault aborts wherever the robot is, glass in hand."""
    for code in (AlarmCode.ROBOT_LOST, AlarmCode.ROBOT_FAULT, AlarmCode.POSITION_FEEDBACK_LOST, AlarmCode.TASK_FAILED):
        text = ALARM_CATALOGUE[code].text
        assert "where the robot stands and the glass" in text, text
        assert text.endswith("Clear, Reset, Start"), text
    assert "CellctlServer RAPID task" in ALARM_CATALOGUE[AlarmCode.ROBOT_LOST].text
    for code in (AlarmCode.LASER_LOST, AlarmCode.CAMERA_LOST, AlarmCode.LASER_READ_FAILED, AlarmCode.CAMERA_GRAB_FAILED):
        text = ALARM_CATALOGUE[code].text
        assert "check" in remedy(text) and "cable" in text and text.endswith("Unhold"), text
