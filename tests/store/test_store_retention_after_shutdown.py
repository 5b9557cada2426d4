"""Retention after the wall clock ran far ahead of the records while the service was off: a plant shutdown
with a right clock ends the hold by itself once the cell records cycles with that clock (and /status says
so truthfully, naming the cell's newest record); a clock set a year ahead and left so deletes nothing
that is not truly older than its period; a step that set a clock right ends its hold the same way.
Peers: sqlite3 on the database file and the image folder on disk; the true time is the test's own."""

from __future__ import annotations

import sqlite3
from datetime import datetime, timedelta
from pathlib import Path
from types import SimpleNamespace

import pytest
from test_store_retention import Clock
from test_store_retention_clock import plc_cycle

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.packml import PackMLMachine
from cellctl.config.store import RetentionConfig
from cellctl.service.retention import StorageRetention
from cellctl.service.retention_plan import GB, DiskUsage
from cellctl.store import AsyncCellStore


@pytest.fixture
async def cell(tmp_path: Path):  # type: ignore[no-untyped-def]
    clock, mono = Clock(), [1000.0]
    db, images = tmp_path / "cell.db", tmp_path / "images"
    store = await AsyncCellStore.open(db, clock=clock)
    alarms = AlarmManager(PackMLMachine())
    alarms.install()

    def start(**cfg: object) -> StorageRetention:
        """A (re)started service's retention task."""
        return StorageRetention(
            RetentionConfig(**cfg), store, alarms, image_dir=images, db_path=db, clock=clock,
            monotonic=lambda: mono[0], disk_usage=lambda _p: DiskUsage(500 * GB, 400 * GB, 100 * GB),
        )  # fmt: skip

    def later(**kw: float) -> None:
        """Time passes and the clock follows it: wall and monotonic clocks move on together."""
        clock.advance(**kw)
        mono[0] += timedelta(**kw).total_seconds()

    async def cycle(n: int) -> int:
        return await store.call(plc_cycle, store._store, images, n)

    def sql(query: str, *args: object) -> list[tuple[object, ...]]:
        con = sqlite3.connect(db)
        try:
            return con.execute(query, args).fetchall()
        finally:
            con.close()

    yield SimpleNamespace(clock=clock, start=start, later=later, cycle=cycle, sql=sql, images=images)
    await store.close()


def _kept_refs(cell: SimpleNamespace, cycle_ids: list[int]) -> int:
    marks = ",".join("?" * len(cycle_ids))
    return cell.sql(f"SELECT COUNT(*) FROM cycle_images WHERE pruned_at IS NULL AND cycle_id IN ({marks})",
                    *cycle_ids)[0][0]  # fmt: skip


async def test_a_plant_shutdown_with_a_right_clock_ends_the_hold_by_itself(cell: SimpleNamespace) -> None:
    before = []
    for n in range(1, 6):  # five days of production, one install a day
        before.append(await cell.cycle(n))
        cell.later(days=1)
    newest_before = cell.sql("SELECT created_at FROM cycles WHERE id = ?", before[-1])[0][0]
    cell.later(days=14)  # a two-week plant shutdown; the clock is right all along
    ret = cell.start(images_days=7, cycles_days=30)
    report = await ret.run_once()
    assert (report.images_pruned, report.cycles_deleted) == (0, 0)
    held = ret.status()["last_error"]
    # It names the cell's newest record with its time, and tells an operator whose clock is right that
    # nothing is to be done.
    assert f"15 days ahead of the newest cycle record (cycle {before[-1]}) of {newest_before[:19]}" in held
    assert "if the clock is right" in held and "nothing to do: pruning resumes by itself" in held
    restarted = datetime.fromisoformat(cell.clock().isoformat())
    n = 100
    while cell.clock() - restarted < timedelta(hours=1):  # production resumes, a pass every 20 min, for an hour
        n += 1
        await cell.cycle(n)
        cell.later(minutes=20)
        await ret.run_once()
    assert ret.status()["last_error"] is None  # confirmed: the hold ended while the service runs
    # The idle days do not count yet: the images from before the shutdown (20 to 16 days old on the
    # wall clock, 5 to 1 days of running) are still there.
    assert _kept_refs(cell, before) == 5 and len(cell.sql("SELECT id FROM cycles")) == 5 + n - 100
    for _ in range(24 * 8):  # eight days of production, an install an hour, a pass after each
        n += 1
        await cell.cycle(n)
        cell.later(hours=1)
        await ret.run_once()
    now = cell.clock()
    old = cell.sql("SELECT COUNT(*) FROM cycle_images WHERE pruned_at IS NULL AND created_at < ?",
                   (now - timedelta(days=7)).isoformat())[0][0]  # fmt: skip
    assert old == 0 and ret.status()["last_error"] is None  # images_days holds again on the wall clock
    on_disk = {p.name for p in cell.images.iterdir()}
    kept = {r[0] for r in cell.sql("SELECT uri FROM cycle_images WHERE pruned_at IS NULL")}
    assert on_disk == kept and all(f"cycle-{c}-shot0.png" not in on_disk for c in before)
    assert [r[0] for r in cell.sql("SELECT id FROM cycles WHERE id IN (?, ?, ?, ?, ?)", *before)] == before  # 30 days


async def test_a_clock_set_a_year_ahead_deletes_nothing_younger_than_its_period(cell: SimpleNamespace) -> None:
    true_offset = timedelta(days=365)
    before = []
    for n in range(1, 11):  # ten days of production, one install a day, with a right clock
        before.append(await cell.cycle(n))
        cell.later(days=1)
    cell.later(hours=6)  # the service is off overnight; the clock comes back a year ahead and stays so
    cell.clock.advance(days=365)
    ret = cell.start(images_days=30, cycles_days=365)
    await ret.run_once()
    assert "366 days ahead of the newest cycle record" in ret.status()["last_error"]
    n, pruned_at_true_age = 100, {}
    for _ in range(40 * 4):  # forty days of production, an install every six hours, a pass after each
        n += 1
        await cell.cycle(n)
        cell.later(hours=6)
        await ret.run_once()
        true_now = cell.clock() - true_offset
        for cid, at in cell.sql("SELECT cycle_id, pruned_at FROM cycle_images WHERE pruned_at IS NOT NULL"):
            if cid in before and cid not in pruned_at_true_age:
                made = datetime.fromisoformat(cell.sql("SELECT created_at FROM cycles WHERE id = ?", cid)[0][0])
                pruned_at_true_age[cid] = true_now - made
        if n == 110:  # two and a half days on: the hold ended, yet every record from before is there
            assert ret.status()["last_error"] is None
            assert _kept_refs(cell, before) == 10 and not pruned_at_true_age
    # Every image from before went, none before it was truly images_days old; records and keys all stayed.
    assert sorted(pruned_at_true_age) == before
    assert min(pruned_at_true_age.values()) >= timedelta(days=30)
    assert cell.sql("SELECT COUNT(*) FROM cycles WHERE id <= ?", before[-1])[0][0] == 10
    assert cell.sql("SELECT COUNT(*) FROM idempotency_keys WHERE cycle_id <= ?", before[-1])[0][0] == 10


async def test_a_step_that_set_a_clock_right_ends_its_hold_by_itself(cell: SimpleNamespace) -> None:
    cell.clock.advance(days=-60)  # the clock runs 60 days behind while the cell records ten installs
    before = []
    for n in range(1, 11):
        before.append(await cell.cycle(n))
        cell.later(hours=2)
    ret = cell.start(images_days=30, cycles_days=365)
    assert (await ret.run_once()).images_pruned == 0 and ret.status()["last_error"] is None
    cell.clock.advance(days=60)  # the time server sets it right
    cell.later(minutes=5)
    await ret.run_once()
    held = ret.status()["last_error"]
    assert "jumped by +1440.0 h" in held and "if it was right, pruning resumes by itself once the cell has" in held
    for n in range(11, 20):  # production goes on with the right clock
        await cell.cycle(n)
        cell.later(minutes=15)
        await ret.run_once()
    assert ret.status()["last_error"] is None
    assert _kept_refs(cell, before) == 10  # 60 days old on the wall clock, a day of running: kept
    cell.later(days=31)
    assert (await ret.run_once()).images_pruned == 10 + 9  # now they are, and the new ones too
