"""A step's recorded ``duration_s`` is its time on the cell's monotonic clock (the recorder's), so a
wall clock stepped back during the step changes nothing; without one, the store never records a
negative duration."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone
from pathlib import Path

from cellctl.cell.events import EventHub
from cellctl.cell.packml import PackMLCommand, PackMLMachine
from cellctl.cell.recorder import StoreRecorder
from cellctl.domain import CycleStep
from cellctl.store import AsyncCellStore, CellStore, CycleRequest


class Clock:
    def __init__(self) -> None:
        self.t = datetime(2026, 3, 1, 10, 0, tzinfo=timezone.utc)

    def __call__(self) -> datetime:
        return self.t


async def test_a_clock_stepped_back_during_a_step_leaves_its_duration_as_measured(tmp_path: Path) -> None:
    wall, mono = Clock(), [100.0]
    store = await AsyncCellStore.open(tmp_path / "cell.db", clock=wall, synchronous="NORMAL")
    try:
        machine = PackMLMachine()
        for cmd in (PackMLCommand.CLEAR, PackMLCommand.RESET, PackMLCommand.START):
            await machine.command(cmd, actor="t", source="t")
            await machine.state_complete()
        cid = (await store.submit_cycle(CycleRequest("side-window", "P-1"), scope="t", key="k", actor="t")).cycle.id
        await store.start_cycle(cid)
        rec = StoreRecorder(store, machine, EventHub(), cid, tmp_path / "images", clock=lambda: mono[0])
        await rec.step_started(CycleStep.ALIGN)
        mono[0] += 4.0  # four seconds of work; meanwhile NTP steps the wall clock back an hour
        wall.t += timedelta(seconds=4) - timedelta(hours=1)
        await rec.step_started(CycleStep.SHOOT)  # closes align
        mono[0] += 1.5
        await rec.close_step(ok=True)
        steps = {s.step: s.duration_s for s in (await store.cycle(cid)).steps}
        assert steps == {CycleStep.ALIGN: 4.0, CycleStep.SHOOT: 1.5}
    finally:
        await store.close()


def test_without_a_measured_time_the_wall_clock_difference_is_never_negative(tmp_path: Path) -> None:
    wall = Clock()
    with CellStore.open(tmp_path / "c.db", clock=wall) as store:
        cid = store.submit_cycle(CycleRequest("side-window", "P-1"), scope="t", key="k", actor="t").cycle.id
        store.start_cycle(cid)
        store.begin_step(cid, CycleStep.ALIGN)
        wall.t -= timedelta(hours=1)
        assert store.finish_step(cid, CycleStep.ALIGN, ok=True, figures={}).duration_s == 0.0
        store.begin_step(cid, CycleStep.SHOOT)
        wall.t += timedelta(seconds=2.5)
        assert store.finish_step(cid, CycleStep.SHOOT, ok=True, figures={}).duration_s == 2.5
