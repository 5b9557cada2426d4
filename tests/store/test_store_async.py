"""Store from asyncio: one store thread, submission order kept, and the wiring the orchestrator uses."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path

import pytest

from cellctl.cell.alarms import AlarmCode, AlarmManager
from cellctl.cell.packml import MachineEvent, PackMLMachine
from cellctl.cell.tags import CycleStep, PackMLCommand, PackMLState
from cellctl.store import AsyncCellStore, CycleRequest, CycleState, IdempotencyConflict
from cellctl.store.db import CellStore


async def test_all_calls_run_on_one_store_thread(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    threads: set[str] = set()
    original = CellStore.append_audit

    def spy(self: CellStore, **kw: object) -> object:
        threads.add(threading.current_thread().name)
        return original(self, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(CellStore, "append_audit", spy)
    store = await AsyncCellStore.open(tmp_path / "cell.db")
    entries = await asyncio.gather(
        *(store.append_audit(actor="op", source="hmi", action=f"a{i}") for i in range(30))
    )
    assert [e.action for e in entries] == [f"a{i}" for i in range(30)]
    assert [e.seq for e in entries] == list(range(1, 31))  # submission order is the log's order
    assert len(threads) == 1 and next(iter(threads)).startswith("cellctl-store")
    assert threading.current_thread().name not in threads
    assert await store.verify_audit_chain() == 30
    await store.close()
    with pytest.raises(RuntimeError, match="closed"):
        await store.cycles()


async def test_concurrent_retries_of_one_key_make_one_cycle(tmp_path: Path) -> None:
    store = await AsyncCellStore.open(tmp_path / "cell.db")
    req = CycleRequest("side-window-A", "P-7", "CAR-3", source="rest")
    results = await asyncio.gather(*(store.submit_cycle(req, scope="rest", key="same", actor="line") for _ in range(20)))
    assert sum(r.created for r in results) == 1 and len({r.cycle.id for r in results}) == 1
    with pytest.raises(IdempotencyConflict):
        await store.submit_cycle(CycleRequest("side-window-B", "P-7", "CAR-3"), scope="rest", key="same", actor="line")
    assert (await store.cycle_counts())[CycleState.QUEUED] == 1
    await store.close()


async def test_orchestrator_wiring_machine_alarms_store(tmp_path: Path) -> None:
    """The wiring the lead's orchestrator uses: audit every machine event, persist every alarm,
    mark install before moving, and an abort mid-install leaves a failed cycle, never a repeat."""
    store = await AsyncCellStore.open(tmp_path / "cell.db")
    await store.recover()
    machine = PackMLMachine()
    alarms = AlarmManager(machine, robot_moving=lambda: True)
    alarms.install()
    events = machine.subscribe_queue()
    alarm_events = alarms.subscribe_queue()

    async def writer() -> None:
        while True:
            ev: MachineEvent = await events.get()
            await store.append_machine_event(ev)
            events.task_done()

    async def alarm_writer() -> None:
        while True:
            a = await alarm_events.get()
            await store.save_alarm(a.alarm)
            alarm_events.task_done()

    tasks = [asyncio.create_task(writer()), asyncio.create_task(alarm_writer())]
    for cmd in (PackMLCommand.CLEAR, None, PackMLCommand.RESET, None, PackMLCommand.START, None):
        if cmd is None:
            await machine.state_complete()
        else:
            await machine.command(cmd, actor="op", source="hmi")
    sub = await store.submit_cycle(CycleRequest("side-window-A", "P-1"), scope="plc", key="1", actor="plc")
    cid = sub.cycle.id
    await store.start_cycle(cid)
    await machine.set_cycle_step(CycleStep.INSTALL)
    await store.begin_step(cid, CycleStep.INSTALL)  # the marker, before the robot is commanded
    await alarms.raise_alarm(AlarmCode.ROBOT_FAULT, source="robot", detail="MotionInterrupted", cycle_id=cid)
    assert machine.state == PackMLState.ABORTING
    await store.fail_cycle(cid, error="aborted during install: robot fault")
    await asyncio.wait_for(events.join(), timeout=10.0)  # a writer that died must fail the test, not hang it
    await asyncio.wait_for(alarm_events.join(), timeout=10.0)
    for t in tasks:
        t.cancel()
    audit = await store.audit_entries()
    assert [(e.action, e.state_after) for e in audit][-2:] == [("cycle_step", "EXECUTE"), ("command:abort", "ABORTING")]
    assert audit[-1].source == f"alarm:{AlarmCode.ROBOT_FAULT.value}"
    saved = await store.alarms()
    assert len(saved) == 1 and saved[0].reaction == PackMLCommand.ABORT and saved[0].cycle_id == cid
    rec = await store.cycle(cid)
    assert rec.state == CycleState.FAILED and rec.install_started and rec.current_step == CycleStep.INSTALL
    await store.close()
