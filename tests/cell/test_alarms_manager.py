"""Alarms: the reaction table against the reference, first-out stop reason, acknowledge, interlocks."""

from __future__ import annotations

import itertools
from collections.abc import Callable
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from cellctl.cell import alarms_doc
from cellctl.cell.alarms import (
    ALARM_CATALOGUE,
    REACTIONS,
    AlarmCode,
    AlarmEvent,
    AlarmEventKind,
    AlarmManager,
    FaultClass,
    Severity,
    UnknownAlarm,
)
from cellctl.cell.packml import CommandBlocked, PackMLMachine
from cellctl.cell.tags import PackMLCommand, PackMLState

S = PackMLState
C = PackMLCommand
ROOT = Path(__file__).resolve().parents[2]


def ticking_clock() -> Callable[[], datetime]:
    t0 = datetime(2026, 11, 22, 8, 0, tzinfo=timezone.utc)
    counter = itertools.count()
    return lambda: t0 + timedelta(seconds=next(counter))


async def machine_in(state: S, **kw: object) -> PackMLMachine:
    """Drive a fresh machine along the normal path Aborted -> ... -> Execute (or Idle/Starting)."""
    m = PackMLMachine(clock=ticking_clock())
    path = [(C.CLEAR, S.CLEARING), (None, S.STOPPED), (C.RESET, S.RESETTING), (None, S.IDLE),
            (C.START, S.STARTING), (None, S.EXECUTE)]  # fmt: skip
    for cmd, reached in path:
        if m.state == state:
            break
        if cmd is None:
            await m.state_complete()
        else:
            await m.command(cmd, actor="test", source="pytest")
        assert m.state == reached
    assert m.state == state
    return m


def manager(m: PackMLMachine | None, moving: bool = False) -> AlarmManager:
    am = AlarmManager(m, robot_moving=lambda: moving, clock=ticking_clock())
    am.install()
    return am


def test_reaction_table_is_the_references_mapping() -> None:
    # cell_conventions.md 1.3 and 4.2: NOK/operator -> Hold; external -> Suspend;
    # robot/controller fault, or PLC heartbeat lost while moving -> Abort (Hold while still).
    expected = {
        FaultClass.MEASUREMENT_NOK: (C.HOLD, C.HOLD),
        FaultClass.OPERATOR_INTERVENTION: (C.HOLD, C.HOLD),
        FaultClass.SENSOR_LOST: (C.HOLD, C.HOLD),
        FaultClass.EXTERNAL_CONDITION: (C.SUSPEND, C.SUSPEND),
        FaultClass.PLC_HEARTBEAT_LOST: (C.HOLD, C.ABORT),
        FaultClass.ROBOT_FAULT: (C.ABORT, C.ABORT),
        FaultClass.SOFTWARE_FAULT: (C.ABORT, C.ABORT),
        FaultClass.WARNING: (None, None),
    }
    assert {fc: (r.when_still, r.when_moving) for fc, r in REACTIONS.items()} == expected
    assert set(ALARM_CATALOGUE) == set(AlarmCode)
    assert ALARM_CATALOGUE[AlarmCode.NO_CAR_IN_POSITION].fault_class == FaultClass.EXTERNAL_CONDITION
    assert ALARM_CATALOGUE[AlarmCode.PLC_NOT_READY].fault_class == FaultClass.EXTERNAL_CONDITION
    assert ALARM_CATALOGUE[AlarmCode.CORNER_NOT_FOUND].fault_class == FaultClass.MEASUREMENT_NOK
    assert ALARM_CATALOGUE[AlarmCode.ROBOT_LOST].fault_class == FaultClass.ROBOT_FAULT


@pytest.mark.parametrize("code", list(AlarmCode), ids=lambda c: c.name)
@pytest.mark.parametrize("moving", [False, True], ids=["still", "moving"])
async def test_each_alarm_in_execute_issues_its_reaction(code: AlarmCode, moving: bool) -> None:
    m = await machine_in(S.EXECUTE)
    am = manager(m, moving)
    a = await am.raise_alarm(code, source="unit", detail="detail text", value=42, cycle_id=7)
    spec = ALARM_CATALOGUE[code]
    expected = REACTIONS[spec.fault_class].command(moving)
    after = {None: S.EXECUTE, C.HOLD: S.HOLDING, C.SUSPEND: S.SUSPENDING, C.ABORT: S.ABORTING}[expected]
    assert m.state == after
    assert (a.code, a.value, a.category, a.cycle_id, a.active) == (code, 42, spec.fault_class, 7, True)
    assert a.message == f"{spec.text}: detail text"
    assert a.reaction == expected and a.severity == REACTIONS[spec.fault_class].severity
    assert am.stop_reason == (a if expected else None)


async def test_plc_heartbeat_reaction_depends_on_motion_and_can_be_overridden() -> None:
    m = await machine_in(S.EXECUTE)
    am = manager(m, moving=False)
    await am.raise_alarm(AlarmCode.PLC_HEARTBEAT_LOST, source="plc", robot_moving=True)
    assert m.state == S.ABORTING and am.stop_reason is not None
    assert am.stop_reason.severity == Severity.CRITICAL


async def test_first_out_stop_reason_is_kept_until_reset() -> None:
    m = await machine_in(S.EXECUTE)
    am = manager(m)
    first = await am.raise_alarm(AlarmCode.CORNER_NOT_FOUND, source="vision")
    assert m.state == S.HOLDING
    await m.state_complete()
    second = await am.raise_alarm(AlarmCode.ROBOT_LOST, source="robot")
    assert m.state == S.ABORTING and second.reaction == C.ABORT
    assert am.stop_reason is not None and am.stop_reason.uid == first.uid  # first-out, not the latest
    await m.state_complete()
    am.acknowledge(first.uid, by="op1")
    assert am.stop_reason.ack_by == "op1"  # the stop reason shows the current record
    await m.command(C.CLEAR, actor="op1", source="hmi")  # Clear is open even with the robot lost
    await m.state_complete()
    with pytest.raises(CommandBlocked, match="Robot controller link lost.*clear its cause first"):
        await m.command(C.RESET, actor="op1", source="hmi")
    am.clear(AlarmCode.ROBOT_LOST, source="robot")
    assert am.stop_reason.uid == first.uid  # still latched in Stopped
    await m.command(C.RESET, actor="op1", source="hmi")
    assert am.stop_reason is None


async def test_a_fault_that_aborts_a_standing_cell_replaces_the_standing_stop_reason() -> None:
    # In Stopped (a commissioning job runs there) the laser lost is named (its Hold cannot act); the robot lost
    # then aborts the cell, and it is the stop reason the operator reads: "Unhold" is refused in Aborted.
    m = await machine_in(S.STOPPED)
    am = manager(m)
    laser = await am.raise_alarm(AlarmCode.LASER_LOST, source="laser")
    assert m.state == S.STOPPED and am.stop_reason is not None and am.stop_reason.uid == laser.uid
    robot = await am.raise_alarm(AlarmCode.ROBOT_LOST, source="robot")
    assert m.state == S.ABORTING
    assert am.stop_reason is not None and am.stop_reason.uid == robot.uid
    await m.state_complete()
    later = await am.raise_alarm(AlarmCode.CAMERA_LOST, source="camera")  # standing in Aborted: first-out kept
    assert later.reaction is None and am.stop_reason.uid == robot.uid


async def test_acknowledge_event_and_condition_alarms() -> None:
    am = manager(None)
    event = await am.raise_alarm(AlarmCode.ALIGNMENT_FAILED, source="align")
    cond = await am.raise_alarm(AlarmCode.LASER_LOST, source="laser")
    assert [a.uid for a in am.current()] == [event.uid, cond.uid]
    acked = am.acknowledge(event.uid, by="alice")
    assert (acked.ack_by, acked.active, acked.acknowledged) == ("alice", False, True)
    assert acked.ack_at is not None and acked.ack_at > acked.raised_at and acked.cleared_at == acked.ack_at
    assert am.acknowledge(event.uid, by="bob").ack_by == "alice"  # the first acknowledgement stays
    assert am.get(event.uid).ack_by == "alice" and am.recent()[-1].uid == event.uid
    c2 = am.acknowledge(cond.uid, by="bob")
    assert c2.active and c2.ack_by == "bob"  # a condition stays active until it clears
    cleared = am.clear(AlarmCode.LASER_LOST, source="laser")
    assert cleared is not None and not cleared.active and am.current() == []
    assert am.clear(AlarmCode.LASER_LOST, source="laser") is None
    with pytest.raises(UnknownAlarm, match="no alarm with uid 'nope'"):
        am.acknowledge("nope", by="alice")
    with pytest.raises(ValueError, match="who acknowledges"):
        am.acknowledge(cond.uid, by="")


async def test_cleared_unacknowledged_condition_stays_listed_but_does_not_block() -> None:
    m = await machine_in(S.IDLE)
    am = manager(m)
    a = await am.raise_alarm(AlarmCode.PLC_NOT_READY, source="plc")
    assert m.state == S.IDLE and a.reaction is None  # Suspend is not possible in Idle
    assert C.START not in m.allowed_commands()
    assert "Line PLC not ready" in m.blocked_commands()[C.START]
    am.clear(AlarmCode.PLC_NOT_READY, source="plc")
    assert [x.uid for x in am.current()] == [a.uid] and am.active() == []
    await m.command(C.START, actor="plc", source="modbus")
    am.acknowledge_all(by="op")
    assert am.current() == []


async def test_unhold_waits_for_the_acknowledgement_of_a_latched_nok() -> None:
    m = await machine_in(S.EXECUTE)
    am = manager(m)
    a = await am.raise_alarm(AlarmCode.RESIDUAL_OVER_LIMIT, source="compensate", detail="0.8 mm after 3 shots")
    await m.state_complete()
    assert m.state == S.HELD
    with pytest.raises(CommandBlocked, match="acknowledge it first"):
        await m.command(C.UNHOLD, actor="op", source="hmi")
    am.acknowledge(a.uid, by="op")
    await m.command(C.UNHOLD, actor="op", source="hmi")
    assert am.stop_reason is None
    await m.state_complete()
    await am.drain()
    assert m.state == S.EXECUTE  # nothing pending: production resumes


async def test_reaction_impossible_now_is_applied_on_entering_execute() -> None:
    m = await machine_in(S.STARTING)
    am = manager(m)
    a = await am.raise_alarm(AlarmCode.NO_CAR_IN_POSITION, source="plc")
    await am.raise_alarm(AlarmCode.DEVICE_SLOW, source="camera")
    assert m.state == S.STARTING and a.reaction is None
    await m.state_complete()  # -> Execute; the pending Suspend follows
    await am.drain()
    assert m.state == S.SUSPENDING
    assert am.get(a.uid).reaction == C.SUSPEND and am.stop_reason is not None and am.stop_reason.uid == a.uid
    await m.state_complete()
    with pytest.raises(CommandBlocked):
        await m.command(C.UNSUSPEND, actor="plc", source="modbus")
    am.clear(AlarmCode.NO_CAR_IN_POSITION, source="plc")
    await m.command(C.UNSUSPEND, actor="plc", source="modbus")  # a warning does not block


async def test_strongest_pending_reaction_wins_on_entering_execute() -> None:
    m = await machine_in(S.STARTING)
    am = manager(m)
    await am.raise_alarm(AlarmCode.NO_CAR_IN_POSITION, source="plc")
    await am.raise_alarm(AlarmCode.CORNER_NOT_FOUND, source="vision")
    await m.state_complete()
    await am.drain()
    assert m.state == S.HOLDING


async def test_duplicates_unknown_codes_and_event_clear_are_handled() -> None:
    am = manager(None)
    a = await am.raise_alarm(AlarmCode.CAMERA_LOST, source="camera")
    assert await am.raise_alarm(AlarmCode.CAMERA_LOST, source="camera") == a
    b = await am.raise_alarm(AlarmCode.CAMERA_LOST, source="camera2")
    assert b.uid != a.uid and len(am.active()) == 2
    with pytest.raises(ValueError, match="unknown alarm code 999"):
        await am.raise_alarm(999, source="x")
    with pytest.raises(ValueError, match="source"):
        await am.raise_alarm(AlarmCode.TASK_FAILED, source="")
    e = await am.raise_alarm(AlarmCode.TASK_FAILED, source="orchestrator")
    with pytest.raises(ValueError, match="acknowledge it instead"):
        am.clear(AlarmCode.TASK_FAILED, source="orchestrator")
    assert am.get(e.uid).active


async def test_observers_get_every_alarm_event() -> None:
    m = await machine_in(S.EXECUTE)
    am = manager(m)
    events: list[AlarmEvent] = []
    am.subscribe(events.append)
    q = am.subscribe_queue()
    a = await am.raise_alarm(AlarmCode.LASER_LOST, source="laser")
    am.acknowledge(a.uid, by="op")
    am.clear(AlarmCode.LASER_LOST, source="laser")
    kinds = [e.kind for e in events]
    assert kinds == [AlarmEventKind.RAISED, AlarmEventKind.REACTED, AlarmEventKind.ACKNOWLEDGED, AlarmEventKind.CLEARED]
    assert events[1].alarm.reaction == C.HOLD and events[-1].alarm.active is False
    assert q.qsize() == 4


def test_committed_alarm_docs_equal_the_generated_tables() -> None:
    doc = ROOT / "docs" / "alarm_reactions.md"
    assert doc.read_text(encoding="utf-8") == alarms_doc.render_markdown(), (
        "docs/alarm_reactions.md is stale: run `python -m cellctl.cell.alarms_doc -o docs/alarm_reactions.md`"
    )


async def test_restored_alarms_are_listed_inactive_and_hold_back_no_recovery() -> None:
    # What a previous run left: a condition present as it stopped, one it had cleared, one already acknowledged.
    # This run raises its own for what persists, so a restored one never blocks a Reset nor stays active.
    earlier = manager(None)
    present = await earlier.raise_alarm(AlarmCode.ROBOT_LOST, source="robot")
    gone = await earlier.raise_alarm(AlarmCode.LASER_LOST, source="laser")
    earlier.clear(AlarmCode.LASER_LOST, source="laser")
    seen = earlier.acknowledge((await earlier.raise_alarm(AlarmCode.CAMERA_LOST, source="camera")).uid, by="op")
    m = await machine_in(S.STOPPED)
    am = manager(m)
    ended = am.restore([present, earlier.get(gone.uid), seen])
    assert [a.uid for a in ended] == [present.uid]  # stored as active: the store must be told it is not
    assert {a.uid for a in am.current()} == {present.uid, gone.uid}  # the acknowledged one is not listed again
    assert am.active() == [] and am.interlocking() == []
    assert (await m.command(C.RESET, actor="op", source="test")).state_after == S.RESETTING
    assert am.get(present.uid).active is False and not am.get(present.uid).acknowledged
