"""The PackML machine against the reference's state model: every edge of the table, every refusal."""

from __future__ import annotations

import asyncio
import itertools
from collections import deque
from pathlib import Path

import pytest

from cellctl.cell import packml, packml_doc
from cellctl.cell.packml import (
    COMMANDED,
    STATE_COMPLETE,
    TRANSITIONS,
    CommandBlocked,
    CommandNotAllowed,
    CommandRefused,
    CycleStepNotAllowed,
    EventKind,
    MachineEvent,
    ModeChangeNotAllowed,
    PackMLMachine,
    StateCompleteNotAllowed,
    Trigger,
)
from cellctl.cell.tags import CycleStep, PackMLCommand, PackMLState, UnitMode

S = PackMLState
C = PackMLCommand
ROOT = Path(__file__).resolve().parents[2]

# The reference's model (cell_conventions.md 1.1), written out independently of packml.py.
RUNNING = {S.RESETTING, S.IDLE, S.STARTING, S.EXECUTE, S.COMPLETING, S.COMPLETE, S.SUSPENDING,
           S.SUSPENDED, S.UNSUSPENDING, S.HOLDING, S.HELD, S.UNHOLDING}  # fmt: skip
CLEARED = RUNNING | {S.CLEARING, S.STOPPED, S.STOPPING}
EXPECTED_COMMANDED: dict[tuple[S, C], S] = {
    (S.STOPPED, C.RESET): S.RESETTING,
    (S.COMPLETE, C.RESET): S.RESETTING,
    (S.IDLE, C.START): S.STARTING,
    (S.EXECUTE, C.COMPLETE): S.COMPLETING,
    (S.EXECUTE, C.HOLD): S.HOLDING,
    (S.HELD, C.UNHOLD): S.UNHOLDING,
    (S.EXECUTE, C.SUSPEND): S.SUSPENDING,
    (S.SUSPENDED, C.UNSUSPEND): S.UNSUSPENDING,
    (S.ABORTED, C.CLEAR): S.CLEARING,
    **{(s, C.STOP): S.STOPPING for s in RUNNING},
    **{(s, C.ABORT): S.ABORTING for s in CLEARED},
}
EXPECTED_SC: dict[S, S] = {
    S.RESETTING: S.IDLE,
    S.STARTING: S.EXECUTE,
    S.EXECUTE: S.COMPLETING,
    S.COMPLETING: S.COMPLETE,
    S.HOLDING: S.HELD,
    S.UNHOLDING: S.EXECUTE,
    S.SUSPENDING: S.SUSPENDED,
    S.UNSUSPENDING: S.EXECUTE,
    S.STOPPING: S.STOPPED,
    S.ABORTING: S.ABORTED,
    S.CLEARING: S.STOPPED,
}

ALL_PAIRS = list(itertools.product(PackMLState, PackMLCommand))
REFUSED_PAIRS = [p for p in ALL_PAIRS if p not in EXPECTED_COMMANDED]


def test_table_is_the_reference_model() -> None:
    assert dict(COMMANDED) == EXPECTED_COMMANDED
    assert dict(STATE_COMPLETE) == EXPECTED_SC
    assert len(TRANSITIONS) == len(EXPECTED_COMMANDED) + len(EXPECTED_SC)
    assert len(EXPECTED_COMMANDED) == 9 + 12 + 15


def test_every_state_is_reachable_from_aborted() -> None:
    seen, todo = {S.ABORTED}, deque([S.ABORTED])
    while todo:
        s = todo.popleft()
        for e in TRANSITIONS:
            if e.source == s and e.target not in seen:
                seen.add(e.target)
                todo.append(e.target)
    assert seen == set(PackMLState) - {S.UNDEFINED}


async def drive_to(target: S, **kw: object) -> PackMLMachine:
    """A fresh machine driven to ``target`` through the table's own edges (shortest path)."""
    m = PackMLMachine(**kw)  # type: ignore[arg-type]
    prev: dict[S, tuple[S, packml.EdgeTrigger]] = {}
    seen, todo = {m.state}, deque([m.state])
    while todo:
        s = todo.popleft()
        for e in TRANSITIONS:
            if e.source == s and e.target not in seen:
                seen.add(e.target)
                prev[e.target] = (s, e.trigger)
                todo.append(e.target)
    path: list[packml.EdgeTrigger] = []
    s = target
    while s != m.state:
        s, trig = prev[s]
        path.append(trig)
    for trig in reversed(path):
        if isinstance(trig, Trigger):
            await m.state_complete()
        else:
            await m.command(trig, actor="test", source="pytest")
    assert m.state == target
    return m


@pytest.mark.parametrize(("state", "command"), sorted(EXPECTED_COMMANDED), ids=lambda x: x.name)
async def test_every_commanded_edge(state: S, command: C) -> None:
    m = await drive_to(state)
    events: list[MachineEvent] = []
    m.subscribe(events.append)
    ev = await m.command(command, actor="alice", source="10.0.0.7")
    assert m.state == EXPECTED_COMMANDED[(state, command)]
    assert (ev.kind, ev.command, ev.state_before, ev.state_after) == (EventKind.COMMAND, command, state, m.state)
    assert (ev.actor, ev.source) == ("alice", "10.0.0.7")
    assert events == [ev]


@pytest.mark.parametrize("state", sorted(EXPECTED_SC), ids=lambda x: x.name)
async def test_every_state_complete_edge(state: S) -> None:
    m = await drive_to(state)
    ev = await m.state_complete(actor="system", source="orchestrator")
    assert m.state == EXPECTED_SC[state]
    assert (ev.kind, ev.command, ev.state_before) == (EventKind.STATE_COMPLETE, None, state)


@pytest.mark.parametrize("state", sorted(set(PackMLState) - {S.UNDEFINED}), ids=lambda x: x.name)
async def test_every_other_pair_is_refused_and_nothing_changes(state: S) -> None:
    m = await drive_to(state)
    events: list[MachineEvent] = []
    m.subscribe(events.append)
    refused = [c for (s, c) in REFUSED_PAIRS if s == state]
    assert set(refused) | m.allowed_commands() == set(PackMLCommand)
    for cmd in refused:
        with pytest.raises(CommandNotAllowed) as err:
            await m.command(cmd, actor="alice", source="pytest")
        assert (err.value.state, err.value.command) == (state, cmd)
        assert state.name.title() in str(err.value) and cmd.name.title() in str(err.value)
        assert set(err.value.allowed) == m.allowed_commands()
    if state not in EXPECTED_SC:
        with pytest.raises(StateCompleteNotAllowed):
            await m.state_complete()
    assert m.state == state and events == []


def test_undefined_state_has_no_edges_and_is_never_an_initial_state() -> None:
    assert packml.commands_allowed_in(S.UNDEFINED) == frozenset()
    assert S.UNDEFINED not in STATE_COMPLETE
    for bad in (S.UNDEFINED, S.EXECUTE, S.IDLE):
        with pytest.raises(ValueError, match="initial_state"):
            PackMLMachine(initial_state=bad)
    assert PackMLMachine().state == S.ABORTED
    assert PackMLMachine(initial_state=S.STOPPED).state == S.STOPPED


async def test_unknown_command_number_is_a_clear_error() -> None:
    m = PackMLMachine()
    with pytest.raises(ValueError, match="unknown PackML command 11"):
        await m.command(11, actor="plc", source="modbus")
    ev = await m.command(9, actor="plc", source="modbus")  # Clear, as an integer off the wire
    assert ev.command is C.CLEAR


async def test_allowed_commands_follow_the_table_everywhere() -> None:
    for state in set(PackMLState) - {S.UNDEFINED}:
        m = await drive_to(state)
        assert m.allowed_commands() == {c for (s, c) in EXPECTED_COMMANDED if s == state}


# --- unit modes ----------------------------------------------------------------------------------


@pytest.mark.parametrize("state", sorted(set(PackMLState) - {S.UNDEFINED}), ids=lambda x: x.name)
async def test_mode_changes_only_in_stopped_idle_aborted(state: S) -> None:
    m = await drive_to(state)
    if state in {S.STOPPED, S.IDLE, S.ABORTED}:
        ev = await m.change_mode(UnitMode.MAINTENANCE, actor="bob", source="hmi")
        assert (ev.kind, ev.mode_before, ev.mode_after, m.mode) == (
            EventKind.MODE, UnitMode.PRODUCTION, UnitMode.MAINTENANCE, UnitMode.MAINTENANCE)  # fmt: skip
        assert ev.state_before == ev.state_after == state
    else:
        with pytest.raises(ModeChangeNotAllowed, match="modes change only in"):
            await m.change_mode(UnitMode.MANUAL, actor="bob", source="hmi")
        assert m.mode == UnitMode.PRODUCTION


@pytest.mark.parametrize("state", [S.EXECUTE, S.HELD, S.COMPLETE], ids=lambda x: x.name)
async def test_asking_for_the_mode_the_cell_is_in_is_taken_in_any_state(state: S) -> None:
    """A PLC that sends its mode selector again (after its own restart, say) changes nothing and is not refused."""
    m = await drive_to(state)
    ev = await m.change_mode(UnitMode.PRODUCTION, actor="plc", source="plc")
    assert (ev.kind, ev.mode_before, ev.mode_after, ev.state_after) == (EventKind.MODE, UnitMode.PRODUCTION, UnitMode.PRODUCTION, state)
    with pytest.raises(ModeChangeNotAllowed):
        await m.change_mode(UnitMode.MANUAL, actor="plc", source="plc")


async def test_mode_change_states_are_configurable_and_invalid_mode_refused() -> None:
    m = PackMLMachine(initial_state=S.STOPPED, mode_change_states={S.STOPPED})
    await m.change_mode(UnitMode.MANUAL, actor="bob", source="hmi")
    await m.command(C.RESET, actor="bob", source="hmi")
    await m.state_complete()
    with pytest.raises(ModeChangeNotAllowed):  # Idle is not in the configured set
        await m.change_mode(UnitMode.PRODUCTION, actor="bob", source="hmi")
    with pytest.raises(ValueError, match="Invalid"):
        await m.change_mode(UnitMode.INVALID, actor="bob", source="hmi")
    with pytest.raises(ValueError, match="unknown unit mode 7"):
        await m.change_mode(7, actor="bob", source="hmi")
    with pytest.raises(ValueError, match="mode_change_states"):
        PackMLMachine(mode_change_states=set())
    with pytest.raises(ValueError, match="initial_mode"):
        PackMLMachine(initial_mode=UnitMode.INVALID)


# --- cycle steps, guards, observers --------------------------------------------------------------


async def test_cycle_step_is_a_sub_state_of_execute() -> None:
    m = await drive_to(S.IDLE)
    with pytest.raises(CycleStepNotAllowed, match="needs Execute"):
        await m.set_cycle_step(CycleStep.ALIGN)
    await m.command(C.START, actor="plc", source="modbus")
    await m.state_complete()
    for step in (CycleStep.CALIBRATE, CycleStep.ALIGN):
        ev = await m.set_cycle_step(step)
        assert ev.kind == EventKind.CYCLE_STEP and ev.step_after == step
    await m.command(C.HOLD, actor="system", source="alarm:1301")
    assert m.cycle_step == CycleStep.ALIGN  # kept while held
    with pytest.raises(CycleStepNotAllowed):
        await m.set_cycle_step(CycleStep.SHOOT)
    await m.state_complete()
    await m.command(C.UNHOLD, actor="op", source="hmi")
    await m.state_complete()
    assert (m.state, m.cycle_step) == (S.EXECUTE, CycleStep.ALIGN)
    await m.set_cycle_step(CycleStep.INSTALL)
    ev = await m.command(C.ABORT, actor="system", source="alarm:1401")
    assert (ev.step_before, ev.step_after, m.cycle_step) == (CycleStep.INSTALL, CycleStep.NONE, CycleStep.NONE)
    with pytest.raises(CycleStepNotAllowed, match="no cycle runs"):
        await m.set_cycle_step(CycleStep.NONE)


async def test_guard_blocks_a_table_allowed_command_and_shows_why() -> None:
    m = PackMLMachine(initial_state=S.STOPPED)
    active = {"on": True}
    m.add_guard(C.RESET, lambda s, c: "alarm 1101 (laser lost) is active" if active["on"] else None)
    assert C.RESET not in m.allowed_commands()
    assert m.status().blocked_commands == {C.RESET: "alarm 1101 (laser lost) is active"}
    with pytest.raises(CommandBlocked, match="laser lost") as err:
        await m.command(C.RESET, actor="op", source="hmi")
    assert isinstance(err.value, CommandRefused) and m.state == S.STOPPED
    active["on"] = False
    await m.command(C.RESET, actor="op", source="hmi")
    assert m.state == S.RESETTING


async def test_observers_see_every_change_in_order_and_a_failing_one_is_isolated() -> None:
    m = PackMLMachine()
    seen: list[int] = []

    def broken(ev: MachineEvent) -> None:
        raise RuntimeError("observer bug")

    m.subscribe(broken)
    unsubscribe = m.subscribe(lambda ev: seen.append(ev.seq))
    q = m.subscribe_queue()
    small = m.subscribe_queue(maxsize=2)
    await m.command(C.CLEAR, actor="op", source="hmi")
    await m.state_complete()
    await m.command(C.RESET, actor="op", source="hmi")
    unsubscribe()
    await m.state_complete()
    got = [q.get_nowait() for _ in range(q.qsize())]
    assert [(e.state_before, e.state_after) for e in got] == [
        (S.ABORTED, S.CLEARING), (S.CLEARING, S.STOPPED), (S.STOPPED, S.RESETTING), (S.RESETTING, S.IDLE)]  # fmt: skip
    assert [e.seq for e in got] == [1, 2, 3, 4] and seen == [1, 2, 3]
    assert [small.get_nowait().seq for _ in range(small.qsize())] == [3, 4]  # oldest dropped
    assert m.status().seq == 4 and m.status().state == S.IDLE


async def test_concurrent_commands_are_serialised() -> None:
    m = await drive_to(S.EXECUTE)
    results = await asyncio.gather(
        *(m.command(c, actor="x", source="y") for c in (C.HOLD, C.SUSPEND, C.STOP)), return_exceptions=True
    )
    hold, suspend, stop = results
    # One writer: each command sees the state the previous one left (the lock is FIFO).
    assert isinstance(hold, MachineEvent) and (hold.state_before, hold.state_after) == (S.EXECUTE, S.HOLDING)
    assert isinstance(suspend, CommandNotAllowed) and suspend.state == S.HOLDING
    assert isinstance(stop, MachineEvent) and (stop.state_before, stop.state_after) == (S.HOLDING, S.STOPPING)


async def test_wait_for_state() -> None:
    m = PackMLMachine()

    async def later() -> None:
        await asyncio.sleep(0.01)
        await m.command(C.CLEAR, actor="op", source="hmi")
        await m.state_complete()

    task = asyncio.create_task(later())
    assert await m.wait_for_state(S.STOPPED, timeout_s=5.0) == S.STOPPED
    await task
    with pytest.raises(TimeoutError):
        await m.wait_for_state(S.EXECUTE, timeout_s=0.02)


# --- docs ----------------------------------------------------------------------------------------


def test_committed_docs_equal_the_generated_table() -> None:
    doc = ROOT / "docs" / "packml_states.md"
    assert doc.read_text(encoding="utf-8") == packml_doc.render_markdown(), (
        "docs/packml_states.md is stale: run `python -m cellctl.cell.packml_doc -o docs/packml_states.md`"
    )


def test_markdown_lists_every_edge(tmp_path: Path) -> None:
    text = packml_doc.render_markdown()
    for e in TRANSITIONS:
        assert f"| {e.source.name.title()} ({e.source.value}) |" in text
    assert packml_doc.main(["-o", str(tmp_path / "x.md")]) == 0
    assert (tmp_path / "x.md").read_text() == text
