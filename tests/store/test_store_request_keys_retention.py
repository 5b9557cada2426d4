"""Retention prunes the idempotency keys that belong to no cycle (a refused PLC request's key) on the
cycles' retention, by the key's own time stamp; a key inside the retention still answers its retry the same.
Checked with sqlite3 on the store file after the pass (an independent reader)."""

from __future__ import annotations

import sqlite3
from collections.abc import AsyncIterator
from datetime import datetime, timedelta, timezone
from pathlib import Path
from types import SimpleNamespace

import pytest

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.packml import PackMLMachine
from cellctl.config.store import RetentionConfig
from cellctl.plc.facade import PlcErrorCode
from cellctl.service.plc_link import PLC_SCOPE, PlcCellLink
from cellctl.service.retention import StorageRetention
from cellctl.store import AsyncCellStore, CellStore, CycleRequest

T0 = datetime(2026, 3, 1, 8, 0, tzinfo=timezone.utc)
UNKNOWN_RECIPE = 99  # not a recipe of the link below: the PLC request is refused and its key stored


class Clock:
    def __init__(self) -> None:
        self.t = T0

    def __call__(self) -> datetime:
        return self.t


class Disk:
    def __call__(self, path: Path) -> SimpleNamespace:
        return SimpleNamespace(total=500 * 2**30, used=0, free=500 * 2**30)


@pytest.fixture
async def cell(tmp_path: Path) -> AsyncIterator[SimpleNamespace]:
    clock = Clock()
    store = await AsyncCellStore.open(tmp_path / "cell.db", clock=clock)
    alarms = AlarmManager(PackMLMachine())
    alarms.install()
    link = PlcCellLink(SimpleNamespace(store=store), {1: "side-window-A"})  # type: ignore[arg-type]
    retention = StorageRetention(
        RetentionConfig(images_days=10, cycles_days=90), store, alarms, image_dir=tmp_path / "images",
        db_path=tmp_path / "cell.db", clock=clock, disk_usage=Disk(), monotonic=lambda: clock().timestamp(),
    )  # fmt: skip
    yield SimpleNamespace(clock=clock, store=store, link=link, retention=retention, db=tmp_path / "cell.db")
    await store.close()


def keys_on_file(db: Path) -> set[tuple[str, str]]:
    """The idempotency keys as another reader of the file sees them."""
    peer = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return {(r[0], r[1]) for r in peer.execute("SELECT scope, key FROM idempotency_keys")}
    finally:
        peer.close()


def finished_cycle(store: CellStore, key: str) -> int:
    cid = store.submit_cycle(CycleRequest("side-window-A", f"P-{key}"), scope="rest", key=key, actor="t").cycle.id
    store.start_cycle(cid)
    store.complete_cycle(cid, result={"ok": True})
    return cid


async def test_a_refused_requests_key_is_pruned_with_the_cycles_and_a_young_one_still_answers(cell: SimpleNamespace) -> None:
    old = await cell.link.start_cycle(7, UNKNOWN_RECIPE, 70)
    await cell.store.call(finished_cycle, cell.store._store, "old-cycle")
    assert not old.accepted and old.error_code == int(PlcErrorCode.UNKNOWN_RECIPE)
    cell.clock.t += timedelta(days=100)
    young = await cell.link.start_cycle(8, UNKNOWN_RECIPE, 80)
    await cell.store.call(finished_cycle, cell.store._store, "young-cycle")
    assert keys_on_file(cell.db) == {(PLC_SCOPE, "7"), (PLC_SCOPE, "8"), ("rest", "old-cycle"), ("rest", "young-cycle")}

    report = await cell.retention.run_once()

    assert report.cycles_deleted == 1
    assert keys_on_file(cell.db) == {(PLC_SCOPE, "8"), ("rest", "young-cycle")}  # the old refusal's key went too
    # The young refusal, inside the retention, is answered the same to its retry.
    again = await cell.link.start_cycle(8, UNKNOWN_RECIPE, 80)
    assert (again.accepted, again.error_code, again.reason) == (young.accepted, young.error_code, young.reason)
    outcome = await cell.link.result_of(8)
    assert outcome is not None and (outcome.ok, outcome.error_code, outcome.part_id) == (False, young.error_code, 80)
    assert await cell.link.result_of(7) is None  # pruned: the id is free again, as a pruned cycle's key is
    actions = [e.action for e in await cell.store.audit_entries()]
    assert "retention.prune_request_keys" in actions
    # "forever" keeps them.
    cell.clock.t += timedelta(days=1000)
    forever = StorageRetention(
        RetentionConfig(images_days=10, cycles_days="forever"), cell.store, cell.retention.alarms,
        image_dir=cell.retention.image_dir, db_path=cell.db, clock=cell.clock, disk_usage=Disk(),
        monotonic=lambda: cell.clock().timestamp(),
    )  # fmt: skip
    await forever.run_once()
    assert keys_on_file(cell.db) == {(PLC_SCOPE, "8"), ("rest", "young-cycle")}


def test_the_store_prunes_only_finished_keys_of_no_cycle_older_than_the_cutoff(tmp_path: Path) -> None:
    clock = Clock()
    with CellStore.open(tmp_path / "c.db", clock=clock) as store:
        store.claim_key("rest-cmd", "done-old", {"command": "start"})
        store.complete_key("rest-cmd", "done-old", {"ok": True})
        store.claim_key("rest-cmd", "open-old", {"command": "stop"})  # still in flight: never pruned under it
        cid = store.submit_cycle(CycleRequest("side-window-A", "P-1"), scope="rest", key="running", actor="t").cycle.id
        store.start_cycle(cid)
        clock.t += timedelta(days=100)
        store.claim_key("rest-cmd", "done-young", {"command": "start"})
        store.complete_key("rest-cmd", "done-young", {"ok": True})
        cutoff = clock() - timedelta(days=90)
        assert store.prune_request_keys(created_before=cutoff, batch=1) == 1
        assert store.prune_request_keys(created_before=cutoff, batch=1) == 0
        assert keys_on_file(tmp_path / "c.db") == {("rest-cmd", "open-old"), ("rest", "running"), ("rest-cmd", "done-young")}
