"""Retention and a wall clock in doubt: a step of a year, or a service started with its clock far ahead,
holds pruning by age (records, images and the PLC's cycle_req_id keys survive), logged once with the
fix; a corrected clock resumes pruning by itself, and a normal pass still prunes."""

from __future__ import annotations

import logging
from datetime import timedelta
from pathlib import Path
from types import SimpleNamespace

import pytest
from test_store_retention import Clock

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.packml import PackMLMachine
from cellctl.config.store import RetentionConfig
from cellctl.domain import CycleStep
from cellctl.service.retention import StorageRetention
from cellctl.service.retention_plan import GB, DiskUsage
from cellctl.store import AsyncCellStore, CellStore, CycleRequest


class Mono:
    """A settable monotonic clock."""

    def __init__(self) -> None:
        self.t = 1000.0


def plc_cycle(store: CellStore, images: Path, n: int) -> int:
    """A finished cycle the PLC asked for with cycle_req_id ``n``, with one image."""
    cid = store.submit_cycle(CycleRequest("side-window-A", f"P-{n}"), scope="plc", key=str(n), actor="plc").cycle.id
    store.start_cycle(cid)
    store.begin_step(cid, CycleStep.SHOOT)
    images.mkdir(parents=True, exist_ok=True)
    (images / f"cycle-{cid}-shot0.png").write_bytes(b"\x89PNG" + b"x" * 996)
    store.add_image(cid, CycleStep.SHOOT, name="shot0", uri=f"cycle-{cid}-shot0.png")
    store.finish_step(cid, CycleStep.SHOOT, ok=True, figures={})
    store.complete_cycle(cid, result={"ok": True})
    return cid


@pytest.fixture
async def cell(tmp_path: Path):  # type: ignore[no-untyped-def]
    clock, mono = Clock(), Mono()
    store = await AsyncCellStore.open(tmp_path / "cell.db", clock=clock)
    alarms = AlarmManager(PackMLMachine())
    alarms.install()

    def make(**cfg: object) -> StorageRetention:
        return StorageRetention(
            RetentionConfig(**cfg), store, alarms, image_dir=tmp_path / "images", db_path=tmp_path / "cell.db",
            clock=clock, monotonic=lambda: mono.t, disk_usage=lambda _p: DiskUsage(500 * GB, 400 * GB, 100 * GB),
        )  # fmt: skip

    def later(**kw: float) -> None:
        """Time passes: both clocks move on together."""
        clock.advance(**kw)
        mono.t += timedelta(**kw).total_seconds()

    async def cycle(n: int) -> int:
        return await store.call(plc_cycle, store._store, tmp_path / "images", n)

    yield SimpleNamespace(clock=clock, mono=mono, store=store, make=make, later=later, cycle=cycle, images=tmp_path / "images")
    await store.close()


async def _known(cell: SimpleNamespace, *req_ids: int) -> list[bool]:
    return [await cell.store.cycle_for_key("plc", str(n)) is not None for n in req_ids]


async def test_a_step_of_a_year_holds_pruning_until_the_clock_is_corrected(
    cell: SimpleNamespace, caplog: pytest.LogCaptureFixture
) -> None:
    for n in range(1, 11):  # ten days of production, one install a day
        await cell.cycle(n)
        cell.later(days=1)
    ret = cell.make(images_days=30, cycles_days=365)
    first = await ret.run_once()
    assert (first.cycles_deleted, first.images_pruned) == (0, 0) and ret.status()["last_error"] is None
    caplog.set_level(logging.WARNING, logger="cellctl.service.retention")
    cell.clock.advance(days=366)  # the wall clock steps a year ahead; five minutes pass
    cell.later(minutes=5)
    report = await ret.run_once()
    assert (report.cycles_deleted, report.images_pruned, report.orphans_deleted) == (0, 0, 0)
    assert len(await cell.store.cycles()) == 10 and len(list(cell.images.iterdir())) == 10
    assert await _known(cell, 1, 5, 10) == [True, True, True]  # a repeated cycle_req_id still replays
    problem = ret.status()["last_error"]
    assert "jumped by +8784.0 h" in problem and "correct the clock, pruning resumes by itself" in problem
    # Production goes on under the wrong clock: its records do not vouch for that clock.
    await cell.cycle(11)
    cell.later(minutes=5)
    assert (await ret.run_once()).cycles_deleted == 0 and len(await cell.store.cycles()) == 11
    assert "days ahead of the newest cycle record (cycle 10)" in ret.status()["last_error"]
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "pruning by age held" in warnings[0].getMessage()  # said once
    # The clock is corrected: one pass sees the step back, the next resumes pruning by age.
    cell.clock.advance(days=-366)
    cell.later(minutes=5)
    await ret.run_once()
    cell.later(minutes=5)
    assert (await ret.run_once()).cycles_deleted == 0 and ret.status()["last_error"] is None
    cell.later(days=25)  # a normal pass prunes what is old on the true clock: the first cycles' images
    report = await ret.run_once()
    assert report.images_pruned == 6 and report.cycles_deleted == 0  # cycles 1-6 (cycle 11 is stamped a year ahead)


async def test_a_service_started_with_its_clock_far_ahead_prunes_nothing_and_a_right_one_prunes(
    cell: SimpleNamespace,
) -> None:
    for n in range(1, 4):
        await cell.cycle(n)
        cell.later(days=20)
    cell.clock.advance(days=-19)  # the newest cycle is a day old; the first one 41 days
    normal = await cell.make(images_days=30, cycles_days=365).run_once()
    assert normal.images_pruned == 1  # the first cycle's image: older than 30 days
    cell.clock.advance(days=366)
    restarted = cell.make(images_days=30, cycles_days=40)
    report = await restarted.run_once()
    assert (report.cycles_deleted, report.images_pruned) == (0, 0) and await _known(cell, 1, 2, 3) == [True] * 3
    assert "367 days ahead of the newest cycle record (cycle 3)" in restarted.status()["last_error"]


async def test_records_made_while_the_clock_was_set_back_keep_their_true_age_after_a_restart(cell: SimpleNamespace) -> None:
    """A PC whose clock battery died boots 400 days behind, records two cycles, and NTP sets it right while the
    service is down: the restarted service (no memory of the step) keeps their records and images, and they go once
    truly older than the retention periods."""
    await cell.cycle(1)
    cell.later(days=2)
    cell.clock.advance(days=-400)
    for n in (2, 3):
        await cell.cycle(n)
        cell.later(days=1)
    cell.clock.advance(days=400)
    await cell.cycle(4)  # recorded with the right clock before the restarted service's first pass
    restarted = cell.make(images_days=30, cycles_days=365)
    report = await restarted.run_once()
    assert (report.cycles_deleted, report.images_pruned) == (0, 0) and restarted.status()["last_error"] is None
    assert await _known(cell, 1, 2, 3, 4) == [True] * 4 and len(list(cell.images.iterdir())) == 4
    cell.later(days=31)  # a month on: every image is older than 30 days on the true clock, no record a year
    report = await restarted.run_once()
    assert (report.cycles_deleted, report.images_pruned) == (0, 4)
    cell.later(days=335)
    assert (await restarted.run_once()).cycles_deleted == 4 and await _known(cell, 1, 2, 3, 4) == [False] * 4
