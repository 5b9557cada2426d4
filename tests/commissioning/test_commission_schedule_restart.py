"""The "calibration check due" reminder counts every glass installed since the last passed check,
however many, after a restart too (``every_cycles = 2000`` with a restart after 1500)."""

from __future__ import annotations

import asyncio
from datetime import datetime, timedelta, timezone
from pathlib import Path

from cellctl.cell.alarms import Alarm, AlarmManager
from cellctl.cell.events import EventHub
from cellctl.cell.packml import PackMLMachine
from cellctl.commissioning.schedule import VerifySchedule
from cellctl.config.calibration_procedure import VerifyCalibrationConfig
from cellctl.domain import AlarmCode
from cellctl.store import AsyncCellStore, CellStore, CycleRequest

CHECKED = datetime(2026, 3, 1, 8, 0, tzinfo=timezone.utc)  # the last passed check


class Clock:
    def __init__(self) -> None:
        self.t = CHECKED - timedelta(days=1)

    def __call__(self) -> datetime:
        return self.t


def _install(store: CellStore, clock: Clock, first: int, n: int, *, state: str = "done") -> None:
    for i in range(first, first + n):
        clock.t += timedelta(seconds=30)
        cid = store.submit_cycle(CycleRequest("side-window", f"P-{i}"), scope="t", key=f"k{i}", actor="t").cycle.id
        store.start_cycle(cid)
        if state == "done":
            store.complete_cycle(cid, result={"ok": True})
        else:
            store.fail_cycle(cid, error="refused")


def _due(alarms: AlarmManager) -> list[Alarm]:
    return [a for a in alarms.current() if a.code == AlarmCode.CALIBRATION_CHECK_DUE and a.active]


async def test_glasses_since_the_last_check_survive_a_restart_and_the_reminder_comes_at_2000(tmp_path: Path) -> None:
    clock = Clock()
    store = await AsyncCellStore.open(tmp_path / "cell.db", clock=clock, synchronous="NORMAL")
    try:
        await store.call(_install, store._store, clock, 0, 300)  # before the check: not counted
        clock.t = CHECKED
        await store.call(_install, store._store, clock, 300, 1500)  # since the check
        await store.call(_install, store._store, clock, 1800, 40, state="failed")  # not installed
        alarms = AlarmManager(PackMLMachine(), robot_moving=lambda: False)
        events = EventHub()
        schedule = VerifySchedule(VerifyCalibrationConfig(every_cycles=2000), store, alarms, events, since=CHECKED)
        await schedule.start()  # the service restarted
        try:
            assert schedule.cycles_since == 1500
            for n in range(500):
                assert not _due(alarms), n
                events.publish("cycle", {"cycle_id": 2000 + n, "state": "done"})
                await asyncio.sleep(0.001)
            await asyncio.sleep(0.05)
            assert [a.message for a in _due(alarms)] and "2000 glasses installed since the last check" in _due(alarms)[0].message
            assert schedule.cycles_since == 2000
        finally:
            await schedule.stop()
    finally:
        await store.close()
