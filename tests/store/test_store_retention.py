"""Retention: images pruned oldest first under both bounds (the record says so), old records deleted,
the audit log kept, the disk-space alarms, the /status figures, and the configuration."""

from __future__ import annotations

import asyncio
import os
import sqlite3
import tomllib
from collections.abc import AsyncIterator, Callable
from datetime import datetime, timedelta, timezone
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from fastapi import HTTPException

from cellctl.api.routes_cycles import image_file
from cellctl.cell.alarms import AlarmCode, AlarmManager
from cellctl.cell.packml import PackMLMachine
from cellctl.cell.tags import CycleStep, PackMLCommand, PackMLState
from cellctl.config import ConfigError, parse_config
from cellctl.config.store import RetentionConfig
from cellctl.service.retention import StorageRetention
from cellctl.service.retention_plan import GB, MB, DiskUsage, plan_images
from cellctl.store import AsyncCellStore, CellStore, CycleRequest, KeptImage, schema

ROOT = Path(__file__).resolve().parents[2]
T0 = datetime(2026, 3, 1, 8, 0, tzinfo=timezone.utc)
C, S = PackMLCommand, PackMLState


class Clock:
    """A settable UTC clock shared by the store and the retention."""

    def __init__(self, t: datetime = T0) -> None:
        self.t = t

    def __call__(self) -> datetime:
        return self.t

    def advance(self, **kw: float) -> None:
        self.t += timedelta(**kw)


def add_cycle(store: CellStore, image_dir: Path, n: int, *, images: int = 2, size: int = 1000, finish: bool = True) -> int:
    """A cycle with ``images`` image files of ``size`` bytes, finished unless told otherwise."""
    cid = store.submit_cycle(CycleRequest("side-window-A", f"P-{n}"), scope="test", key=f"k-{n}", actor="t").cycle.id
    store.start_cycle(cid)
    store.begin_step(cid, CycleStep.SHOOT)
    image_dir.mkdir(parents=True, exist_ok=True)
    for k in range(images):
        name = f"shot{k}"
        (image_dir / f"cycle-{cid}-{name}.png").write_bytes(b"\x89PNG" + b"x" * (size - 4))
        store.add_image(cid, CycleStep.SHOOT, name=name, uri=f"cycle-{cid}-{name}.png")
    store.finish_step(cid, CycleStep.SHOOT, ok=True, figures={"n": n})
    if finish:
        store.complete_cycle(cid, result={"ok": True})
    return cid


# -- the store ------------------------------------------------------------------------------------


def test_migration_3_adds_the_pruned_columns_to_an_existing_database(tmp_path: Path) -> None:
    path = tmp_path / "old.db"
    raw = sqlite3.connect(path, isolation_level=None)
    schema.migrate(raw, schema.MIGRATIONS[:2])  # a database written before retention existed
    raw.execute(
        "INSERT INTO cycles (idempotency_scope, idempotency_key, recipe, part_id, source, actor, state, created_at) "
        "VALUES ('s', 'k', 'r', 'p', 'api', 'a', 'done', ?)",
        (T0.isoformat(),),
    )
    raw.execute("INSERT INTO cycle_images (cycle_id, step, name, uri, created_at) VALUES (1, 3, 'final', 'cycle-1-final.png', ?)",
                (T0.isoformat(),))  # fmt: skip
    raw.close()
    with CellStore.open(path) as store:
        assert store.info().schema_version == len(schema.MIGRATIONS) >= 3
        (img,) = store.cycle(1).images
        assert (img.name, img.pruned, img.pruned_at, img.pruned_reason) == ("final", False, None, None)
        cols = {r[1] for r in store._conn.execute("PRAGMA table_info(cycle_images)")}
        assert {"pruned_at", "pruned_reason"} <= cols


def test_a_pruned_image_keeps_its_reference_saying_when_and_why(tmp_path: Path) -> None:
    clock = Clock()
    with CellStore.open(tmp_path / "c.db", clock=clock) as store:
        cid = add_cycle(store, tmp_path / "images", 1)
        kept = store.kept_images()
        assert [k.uri for k in kept] == [f"cycle-{cid}-shot0.png", f"cycle-{cid}-shot1.png"]
        assert not any(k.cycle_active for k in kept)
        assert store.mark_images_pruned([f"cycle-{cid}-shot0.png"], reason="retention: older than 30 days") == 1
        shot0, shot1 = store.cycle(cid).images
        assert shot0.pruned and shot0.pruned_at == T0 and shot0.pruned_reason == "retention: older than 30 days"
        assert not shot1.pruned
        assert [k.uri for k in store.kept_images()] == [f"cycle-{cid}-shot1.png"]
        assert store.pruned_only([f"cycle-{cid}-shot0.png", f"cycle-{cid}-shot1.png", "other.png"]) == {f"cycle-{cid}-shot0.png"}
        with pytest.raises(ValueError, match="why"):
            store.mark_images_pruned(["x"], reason=" ")


def test_old_cycle_records_go_with_their_steps_images_and_keys_but_the_audit_log_stays(tmp_path: Path) -> None:
    clock = Clock()
    with CellStore.open(tmp_path / "c.db", clock=clock) as store:
        old = [add_cycle(store, tmp_path / "images", n) for n in range(3)]
        store.append_audit(actor="op", source="test", action="command:start", cycle_id=old[0])
        clock.advance(days=400)
        running = add_cycle(store, tmp_path / "images", 10, finish=False)
        young = add_cycle(store, tmp_path / "images", 11)
        ids, uris = store.prune_cycles(created_before=clock() - timedelta(days=365), batch=2)
        assert ids == old[:2] and sorted(uris) == sorted(f"cycle-{c}-shot{k}.png" for c in old[:2] for k in (0, 1))
        ids, _ = store.prune_cycles(created_before=clock() - timedelta(days=365), batch=2)
        assert ids == old[2:]
        assert store.prune_cycles(created_before=clock() - timedelta(days=365)) == ([], [])
        assert [c.id for c in store.cycles()] == [young, running]
        for table in ("cycle_steps", "cycle_images", "idempotency_keys"):
            left = {r[0] for r in store._conn.execute(f"SELECT cycle_id FROM {table}")}
            assert left == {running, young}, table
        assert store.cycle_for_key("test", "k-0") is None  # its key went with it
        # The audit log is kept whole, and still refuses deletes.
        assert store.verify_audit_chain() == 1 and store.audit_entries()[0].cycle_id == old[0]
        with pytest.raises(sqlite3.IntegrityError, match="append-only"):
            store._conn.execute("DELETE FROM audit_log")


def test_old_inactive_alarms_are_deleted_active_ones_kept(tmp_path: Path) -> None:
    clock = Clock()
    with CellStore.open(tmp_path / "c.db", clock=clock) as store:
        am = AlarmManager(None, clock=clock)
        saved: list[Any] = []
        am.subscribe(lambda ev: saved.append(ev.alarm))

        async def raise_two() -> None:
            await am.raise_alarm(AlarmCode.CORNER_NOT_FOUND, source="vision")
            await am.raise_alarm(AlarmCode.LASER_LOST, source="laser")

        asyncio.run(raise_two())
        corner = next(a for a in am.current() if a.code == AlarmCode.CORNER_NOT_FOUND)
        am.acknowledge(corner.uid, by="op")
        for a in am.current() + am.recent():
            store.save_alarm(a)
        clock.advance(days=800)
        assert store.prune_alarms(raised_before=clock() - timedelta(days=730)) == 1
        assert [a.code for a in store.alarms()] == [AlarmCode.LASER_LOST]  # still active: kept


def test_database_size_reports_pages_and_tables(tmp_path: Path) -> None:
    with CellStore.open(tmp_path / "c.db") as store:
        add_cycle(store, tmp_path / "images", 1)
        size = store.database_size(per_table=True)
        assert size.page_size > 0 and size.used_bytes <= size.total_bytes
        if size.tables is not None:  # SQLite with dbstat
            assert "cycles" in size.tables and "cycle_steps" in size.tables


# -- the plan -------------------------------------------------------------------------------------


def _kept(n: int, t: datetime, *, active: bool = False) -> KeptImage:
    return KeptImage(n, n, f"cycle-{n}-final.png", t, active)


def test_the_plan_takes_the_oldest_first_until_under_both_bounds() -> None:
    from cellctl.service.retention_plan import FileInfo

    kept = [_kept(i, T0 + timedelta(hours=i)) for i in range(1, 6)]
    files = {k.uri: FileInfo(MB, 0.0) for k in kept}
    now = T0 + timedelta(days=1)
    plan = plan_images(kept, files, now=now, images_days=30, max_bytes=int(2.5 * MB))
    assert [n for ns in plan.prune.values() for n in ns] == [f"cycle-{i}-final.png" for i in (1, 2, 3)]
    assert list(plan.prune) == ["retention: images over their bound of 2.5 MB"]
    assert (plan.kept_count, plan.kept_bytes, plan.oldest_kept) == (2, 2 * MB, T0 + timedelta(hours=4))
    # By age: everything older than 12 h goes, even far under the size bound.
    plan = plan_images(kept, files, now=T0 + timedelta(hours=15), images_days=0.5, max_bytes=100 * MB)
    assert plan.prune == {"retention: older than 0.5 days": ["cycle-1-final.png", "cycle-2-final.png"]}
    # A running cycle's images are never taken; the next oldest go instead.
    kept[0] = _kept(1, T0 + timedelta(hours=1), active=True)
    plan = plan_images(kept, files, now=now, images_days=30, max_bytes=int(2.5 * MB))
    assert [n for ns in plan.prune.values() for n in ns] == [f"cycle-{i}-final.png" for i in (2, 3, 4)]
    # A reference without a file is reported missing; no bound: nothing planned.
    plan = plan_images(kept + [_kept(9, T0)], files, now=now, images_days=None, max_bytes=None)
    assert plan.missing == ["cycle-9-final.png"] and plan.prune == {} and plan.kept_count == 5


# -- the task -------------------------------------------------------------------------------------


class FakeDisk:
    def __init__(self, free_gb: float) -> None:
        self.free = int(free_gb * GB)

    def __call__(self, _path: Path) -> DiskUsage:
        return DiskUsage(500 * GB, 500 * GB - self.free, self.free)


@pytest.fixture
async def rig(tmp_path: Path) -> AsyncIterator[SimpleNamespace]:
    clock = Clock()
    store = await AsyncCellStore.open(tmp_path / "cell.db", clock=clock)
    machine = PackMLMachine()
    alarms = AlarmManager(machine)
    alarms.install()
    disk = FakeDisk(100.0)
    step = SimpleNamespace(value=CycleStep.NONE)

    def make(**cfg: Any) -> StorageRetention:
        return StorageRetention(
            RetentionConfig(**cfg), store, alarms, image_dir=tmp_path / "images", db_path=tmp_path / "cell.db",
            clock=clock, disk_usage=disk, cycle_step=lambda: step.value, monotonic=lambda: clock().timestamp(),
        )  # fmt: skip

    def sync(fn: Callable[[CellStore], Any]) -> Any:
        return store.call(fn, store._store)

    yield SimpleNamespace(clock=clock, store=store, machine=machine, alarms=alarms, disk=disk, step=step, make=make,
                          sync=sync, images=tmp_path / "images", tmp=tmp_path)  # fmt: skip
    await store.close()


async def test_a_pass_prunes_images_oldest_first_and_the_image_route_answers_410(rig: SimpleNamespace) -> None:
    ids = []
    for n in range(6):
        ids.append(await rig.sync(lambda s, n=n: add_cycle(s, rig.images, n, size=200_000)))
        rig.clock.advance(minutes=10)
    ret = rig.make(images_max_gb=1.0 * MB / GB)  # 1 MB, less room for the next cycle's 0.4 MB: 3 of the 12 images
    report = await ret.run_once()
    assert report.images_pruned == 9 and report.cycles_deleted == 0
    left = sorted(p.name for p in rig.images.iterdir())
    assert left == sorted([f"cycle-{ids[4]}-shot1.png", f"cycle-{ids[5]}-shot0.png", f"cycle-{ids[5]}-shot1.png"])
    status = ret.status()
    assert status["images_count"] == 3 and status["images_mb"] == pytest.approx(0.6 / 1.048576, abs=0.01)
    assert status["oldest_image_utc"] == (T0 + timedelta(minutes=40)).isoformat(timespec="seconds")
    assert status["pruned_since_start"]["images"] == 9
    # The first cycle's record still lists its images, each saying it was pruned and why.
    record = await rig.store.cycle(ids[0])
    assert all(i.pruned and "over their bound" in (i.pruned_reason or "") for i in record.images)
    # GET /cycles/{id}/images/{name} of a pruned image: 410, not 500 and not a file.
    orch = SimpleNamespace(store=rig.store, image_dir=rig.images)
    with pytest.raises(HTTPException) as gone:
        await image_file(orch, ids[0], "shot0")  # type: ignore[arg-type]
    assert gone.value.status_code == 410
    assert await image_file(orch, ids[5], "shot0") == rig.images / f"cycle-{ids[5]}-shot0.png"  # type: ignore[arg-type]
    # A second pass finds nothing more to do.
    assert (await ret.run_once()).images_pruned == 0


async def test_a_pass_prunes_by_age_deletes_old_orphans_and_leftovers_and_marks_missing_files(rig: SimpleNamespace) -> None:
    first = await rig.sync(lambda s: add_cycle(s, rig.images, 1))
    rig.clock.advance(days=20)
    second = await rig.sync(lambda s: add_cycle(s, rig.images, 2))
    running = await rig.sync(lambda s: add_cycle(s, rig.images, 3, finish=False))
    (rig.images / f"cycle-{second}-shot1.png").unlink()  # gone behind the store's back
    old_orphan, young_orphan = rig.images / "cycle-99-final.png", rig.images / "cycle-98-final.png"
    for p in (old_orphan, young_orphan):
        p.write_bytes(b"x" * 10)
    old = (rig.clock() - timedelta(days=31)).timestamp()
    os.utime(old_orphan, (old, old))
    os.utime(young_orphan, (rig.clock().timestamp(), rig.clock().timestamp()))
    # A file whose reference already says pruned (a crash between the mark and the unlink).
    await rig.store.mark_images_pruned([f"cycle-{second}-shot0.png"], reason="retention: test")
    rig.clock.advance(days=11)  # the first cycle's images are 31 days old now
    report = await rig.make(images_days=30).run_once()
    assert (report.images_pruned, report.images_missing, report.orphans_deleted) == (2, 1, 1)
    assert sorted(p.name for p in rig.images.iterdir()) == sorted(
        [young_orphan.name, f"cycle-{running}-shot0.png", f"cycle-{running}-shot1.png"]
    )
    first_rec, second_rec = await rig.store.cycle(first), await rig.store.cycle(second)
    assert {i.pruned_reason for i in first_rec.images} == {"retention: older than 30 days"}
    assert [i.pruned_reason for i in second_rec.images] == ["retention: test", "file missing on disk when retention looked"]


async def test_old_records_are_pruned_with_an_audit_entry_and_the_chain_verifies(rig: SimpleNamespace) -> None:
    old = await rig.sync(lambda s: add_cycle(s, rig.images, 1))
    await rig.store.append_audit(actor="op", source="test", action="command:start")
    rig.clock.advance(days=100)
    young = await rig.sync(lambda s: add_cycle(s, rig.images, 2))
    report = await rig.make(images_days=10, cycles_days=90).run_once()
    assert report.cycles_deleted == 1 and [c.id for c in await rig.store.cycles()] == [young]
    entries = await rig.store.audit_entries()
    assert [e.action for e in entries] == ["command:start", "retention.prune_cycles"]
    assert entries[1].params["cycles"] == 1 and entries[1].params["first_id"] == old
    assert await rig.store.verify_audit_chain() == 2
    # "forever" keeps them.
    rig.clock.advance(days=1000)
    assert (await rig.make(images_days=10, cycles_days="forever").run_once()).cycles_deleted == 0


async def _to_execute(m: PackMLMachine) -> None:
    for cmd in (C.CLEAR, C.RESET, C.START):
        await m.command(cmd, actor="t", source="t")
        await m.state_complete()


async def test_disk_alarms_warn_first_then_hold_and_clear_when_space_is_back(rig: SimpleNamespace) -> None:
    await _to_execute(rig.machine)
    ret = rig.make(disk_warn_free_gb=10, disk_stop_free_gb=2)
    assert await ret.check_disk() == "ok" and rig.alarms.active() == []
    rig.disk.free = 8 * GB
    assert await ret.check_disk() == "low"
    (warn,) = rig.alarms.active()
    assert warn.code == AlarmCode.DISK_SPACE_LOW and warn.source == "storage" and "8.00 GB free" in warn.message
    assert rig.machine.state is S.EXECUTE  # a warning changes nothing
    rig.disk.free = int(1.5 * GB)
    assert await ret.check_disk() == "critical"
    crit = rig.alarms.find_active(AlarmCode.DISK_SPACE_CRITICAL, "storage")
    assert crit is not None and crit.reaction is C.HOLD and rig.machine.state is S.HOLDING
    await rig.machine.state_complete()
    assert rig.alarms.recovery_guard(S.HELD, C.UNHOLD) is not None  # Unhold refused while the disk is full
    status = ret.status()
    assert status["disk"] == "critical" and status["free_disk_gb"] == 1.5
    # Just above the threshold is not enough (no flapping); well above clears both in turn.
    rig.disk.free = int(2.05 * GB)
    await ret.check_disk()
    assert rig.alarms.find_active(AlarmCode.DISK_SPACE_CRITICAL, "storage") is not None
    rig.disk.free = 5 * GB
    assert await ret.check_disk() == "low"
    assert [a.code for a in rig.alarms.active()] == [AlarmCode.DISK_SPACE_LOW]
    assert rig.alarms.recovery_guard(S.HELD, C.UNHOLD) is None  # a warning blocks nothing
    rig.disk.free = 50 * GB
    assert await ret.check_disk() == "ok" and rig.alarms.active() == []


async def test_the_stop_alarm_waits_for_the_install_step_to_end(rig: SimpleNamespace) -> None:
    await _to_execute(rig.machine)
    ret = rig.make(disk_warn_free_gb=10, disk_stop_free_gb=2)
    rig.disk.free = 1 * GB
    rig.step.value = CycleStep.INSTALL
    assert await ret.check_disk() == "critical"
    assert rig.alarms.find_active(AlarmCode.DISK_SPACE_CRITICAL, "storage") is None and rig.machine.state is S.EXECUTE
    assert ret._fig.deferred  # the loop looks again every DEFERRED_CHECK_S
    rig.step.value = CycleStep.NONE
    await ret.check_disk()
    assert rig.alarms.find_active(AlarmCode.DISK_SPACE_CRITICAL, "storage") is not None and rig.machine.state is S.HOLDING


async def test_the_background_task_prunes_after_a_finished_cycle_and_stops_cleanly(rig: SimpleNamespace) -> None:
    from cellctl.cell.events import EventHub

    events = EventHub()
    ret = StorageRetention(
        RetentionConfig(images_max_gb=0.45 * MB / GB, period_s=3600), rig.store, rig.alarms,
        image_dir=rig.images, db_path=rig.tmp / "cell.db", events=events, clock=rig.clock, disk_usage=rig.disk,
    )  # fmt: skip
    await ret.start()
    try:
        assert ret.status()["disk"] == "ok" and ret.status()["database_mb"] > 0  # measured in start()
        for _ in range(200):  # the first pass runs in the task, at once
            await asyncio.sleep(0.01)
            if ret.status()["last_pass_utc"] is not None:
                break
        assert ret.status()["images_count"] == 0
        for n in range(3):
            await rig.sync(lambda s, n=n: add_cycle(s, rig.images, n, size=100_000))
            rig.clock.advance(minutes=1)
        events.publish("cycle", {"cycle_id": 3, "state": "done"})
        for _ in range(200):
            await asyncio.sleep(0.01)
            if ret.status()["pruned_since_start"]["images"]:
                break
        # 0.6 MB of images, a bound of 0.45 MB and room for one more cycle (0.2 MB): two images stay.
        assert sum(p.stat().st_size for p in rig.images.iterdir()) == 200_000
        assert ret.status()["pruned_since_start"]["images"] == 4
    finally:
        await ret.stop()
    assert events.subscribers == 0


# -- configuration ----------------------------------------------------------------------------------


def test_the_shipped_configs_carry_a_retention_section() -> None:
    for name in ("sim.toml", "hardware.example.toml"):
        data = tomllib.loads((ROOT / "config" / name).read_text())
        r = data["store"]["retention"]
        RetentionConfig(**r)  # valid as written
        assert {"images_days", "images_max_gb", "cycles_days", "alarms_days", "disk_warn_free_gb", "disk_stop_free_gb"} <= set(r)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"images_days": 400, "cycles_days": 365}, "would outlive its cycle record"),
        ({"disk_warn_free_gb": 1, "disk_stop_free_gb": 2}, "the warning must come before the stop"),
        ({"alarms_days": 0}, 'days above 0, or "forever"'),
        ({"images_max_gb": 0}, "greater than 0"),
        ({"audit_days": 10}, "unknown field"),
    ],
)
def test_bad_retention_settings_are_refused_naming_the_field(fields: dict[str, Any], message: str) -> None:
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data.setdefault("store", {})["retention"] = fields
    with pytest.raises(ConfigError, match=message):
        parse_config(data, "test")


def test_the_room_left_for_the_next_cycle_is_the_largest_recent_cycle() -> None:
    from cellctl.service.retention_plan import FileInfo, cycle_headroom, largest_cycle_in_names

    kept = [KeptImage(i, c, f"cycle-{c}-shot{i}.png", T0, False) for i, c in enumerate([1, 1, 2, 3, 3, 3])]
    files = {k.uri: FileInfo(100 * (k.cycle_id), 0.0) for k in kept}
    assert cycle_headroom(kept, files, bound=10_000) == 900  # cycle 3: three images of 300 bytes
    assert cycle_headroom(kept, files, bound=1_000) == 500  # never more than half the bound
    assert largest_cycle_in_names(files) == 900
    assert largest_cycle_in_names({"cycle-x-final.png": FileInfo(5, 0.0)}) == 0


async def test_the_service_reports_storage_figures_in_status(tmp_path: Path) -> None:
    from service_test_support import api_client, running_service, sim_config

    config = sim_config(plc={"enabled": False})
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        for _ in range(200):  # the first pass runs in the background, at once
            storage = (await client.get("/status")).json()["storage"]
            if storage["last_pass_utc"] is not None:
                break
            await asyncio.sleep(0.01)
        assert storage["images_mb"] == 0 and storage["images_count"] == 0 and storage["oldest_image_utc"] is None
        assert storage["database_mb"] > 0 and storage["free_disk_gb"] > 0 and storage["disk"] in ("ok", "low", "critical")
        assert storage["retention"]["audit_log"] == "kept (never pruned)"
        assert storage["retention"]["images_max_gb"] == config.store.retention.images_max_gb
        assert service.extras["retention"]._task is not None  # the background task runs
    assert service.extras["retention"]._task is None  # and stopped with the service
