"""Alarm retention: after ``alarms_days`` only acknowledged alarms of no kept cycle record go. A part record
kept for ``cycles_days`` keeps its alarms (alarms_days shorter than cycles_days is accepted), an alarm nobody
acknowledged stays (and its later acknowledgement is kept), and once the cycle record is pruned its alarms
follow. Truth: the alarms the test raised; peer: sqlite3 on the database file."""

from __future__ import annotations

import sqlite3
from datetime import timedelta
from pathlib import Path

from test_store_retention import Clock, add_cycle

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.packml import PackMLMachine
from cellctl.config.store import RetentionConfig
from cellctl.domain import Alarm, AlarmCode
from cellctl.service.retention import StorageRetention
from cellctl.service.retention_plan import GB, DiskUsage
from cellctl.store import AsyncCellStore, CellStore


async def test_alarms_of_kept_part_records_and_unacknowledged_alarms_are_kept(tmp_path: Path) -> None:
    clock, mono = Clock(), [1000.0]
    db, images = tmp_path / "cell.db", tmp_path / "images"
    store = await AsyncCellStore.open(db, clock=clock)
    alarms = AlarmManager(PackMLMachine(), clock=clock)
    alarms.install()
    events: list[Alarm] = []
    alarms.subscribe(lambda ev: events.append(ev.alarm))

    def rows() -> dict[str, tuple[int, str | None, int | None]]:
        con = sqlite3.connect(db)
        try:
            return {r[0]: (r[1], r[2], r[3]) for r in con.execute("SELECT uid, code, ack_at, cycle_id FROM alarms")}
        finally:
            con.close()

    def later(**kw: float) -> None:
        clock.advance(**kw)
        mono[0] += timedelta(**kw).total_seconds()

    async def settle() -> None:
        while events:  # every alarm event saved, as the service does
            await store.save_alarm(events.pop(0))

    cid = await store.call(add_cycle, store._store, images, 1)
    corner = await alarms.raise_alarm(AlarmCode.CORNER_NOT_FOUND, source="cycle", detail="arc", cycle_id=cid)
    alarms.acknowledge(corner.uid, by="operator")  # the part's alarm, acknowledged
    laser = await alarms.raise_alarm(AlarmCode.LASER_LOST, source="laser")
    alarms.acknowledge(laser.uid, by="operator")
    alarms.clear(AlarmCode.LASER_LOST, source="laser")  # a device alarm of no cycle, acknowledged and gone
    robot = await alarms.raise_alarm(AlarmCode.DEVICE_SLOW, source="watchdog")
    alarms.clear(AlarmCode.DEVICE_SLOW, source="watchdog")  # gone, but nobody acknowledged it
    await settle()
    assert {u: r[0] for u, r in rows().items()} == {corner.uid: 1302, laser.uid: int(AlarmCode.LASER_LOST),
                                                     robot.uid: int(AlarmCode.DEVICE_SLOW)}  # fmt: skip
    ret = StorageRetention(
        RetentionConfig(images_days=30, cycles_days=365, alarms_days=90), store, alarms, image_dir=images, db_path=db,
        clock=clock, monotonic=lambda: mono[0], disk_usage=lambda _p: DiskUsage(500 * GB, 400 * GB, 100 * GB),
    )  # fmt: skip
    await ret.run_once()
    later(days=120)
    await store.call(add_cycle, store._store, images, 2)  # production goes on
    assert (await ret.run_once()).alarms_deleted == 1
    left = rows()
    assert set(left) == {corner.uid, robot.uid}  # the device alarm went; the part's and the unacknowledged stayed
    record = await store.call(CellStore.cycle_actions, store._store, cid)
    assert [a.uid for a in record.alarms] == [corner.uid]  # the part record still lists its alarm
    alarms.acknowledge(robot.uid, by="operator")  # acknowledged late: the acknowledgement is kept, then pruned
    await settle()
    assert rows()[robot.uid][1] is not None
    assert (await ret.run_once()).alarms_deleted == 1 and set(rows()) == {corner.uid}
    later(days=250)  # the cycle's record is pruned after cycles_days; its alarm goes with the next pass
    report = await ret.run_once()
    assert report.cycles_deleted == 1 and report.alarms_deleted == 1 and rows() == {}
    await store.close()
