"""Retention vs MQTT results: a cycle whose result was never queued is kept while publication is on, and
when publication is off its deletion is counted and reported to the plant (outbox/dropped, on a real broker)."""

from __future__ import annotations

import asyncio
import json
import logging
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
from mosquitto_support import running_broker, subscribed
from mqtt_publisher_support import NAMES, publisher_config
from test_mqtt_outbox_store import _finish, _NoAlarms

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.events import EventHub
from cellctl.cell.packml import PackMLMachine
from cellctl.config.store import RetentionConfig
from cellctl.mqtt.bridge import EventBridge
from cellctl.mqtt.outbox import Outbox
from cellctl.mqtt.publisher import MqttPublisher
from cellctl.mqtt.topics import CellTopics
from cellctl.service.retention import StorageRetention
from cellctl.service.retention_plan import GB, DiskUsage
from cellctl.store import AsyncCellStore

T0 = datetime(2026, 3, 1, 8, 0, tzinfo=timezone.utc)


class Clock:
    def __init__(self) -> None:
        self.t = T0

    def __call__(self) -> datetime:
        return self.t


def _bridge(store: AsyncCellStore, outbox: Outbox | None = None) -> EventBridge:
    return EventBridge(outbox or Outbox(store, 100), CellTopics(NAMES), EventHub(), alarms=_NoAlarms(),
                       state_now=lambda: ("EXECUTE", "PRODUCTION", "NONE"), calibration_now=lambda: {"version": 3})  # fmt: skip


def _retention(store: AsyncCellStore, tmp: Path, clock: Clock, *, mqtt_results: bool) -> StorageRetention:
    alarms = AlarmManager(PackMLMachine())
    alarms.install()
    return StorageRetention(
        RetentionConfig(images_days=10, cycles_days=30), store, alarms, image_dir=tmp / "images", db_path=tmp / "cell.db",
        clock=clock, disk_usage=lambda _p: DiskUsage(500 * GB, 100 * GB, 400 * GB), mqtt_results=mqtt_results,
        monotonic=lambda: clock.t.timestamp(),
    )  # fmt: skip


async def _results(store: AsyncCellStore) -> list[int]:
    rows = await store.outbox_pending(limit=1000)
    return [json.loads(r.payload)["cycle_id"] for r in rows if r.topic.endswith("/result")]


async def test_with_publication_on_a_cycle_whose_result_is_not_queued_is_kept_until_it_is(tmp_path: Path) -> None:
    clock = Clock()
    store = await AsyncCellStore.open(tmp_path / "cell.db", clock=clock)
    sync = store._store
    try:
        history = await store.call(_finish, sync, 1)  # before MQTT: history, never published
        await (b := _bridge(store)).start()  # the mark at cycle 1
        await b.stop()
        waiting = [await store.call(_finish, sync, n) for n in (2, 3)]  # ended, the bridge not running yet
        await (ret := _retention(store, tmp_path, clock, mqtt_results=True)).run_once()
        clock.t += timedelta(days=40)
        report = await ret.run_once()
        assert report.cycles_deleted == 1 and [c.id for c in await store.cycles()] == sorted(waiting, reverse=True)
        assert history not in [c.id for c in await store.cycles()]
        await (b := _bridge(store)).start()  # the catch-up queues both, in order
        await b.stop()
        assert await _results(store) == waiting and (await store.outbox_counts()).dropped_results == 0
        report = await ret.run_once()
        assert report.cycles_deleted == 2  # queued now: retention may take them
    finally:
        await store.close()


async def test_with_publication_off_pruned_results_are_counted_and_reported_to_the_broker(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    clock = Clock()
    store = await AsyncCellStore.open(tmp_path / "cell.db", clock=clock)
    sync = store._store
    try:
        await (b := _bridge(store)).start()  # publication was set up once: the mark at the newest cycle (none)
        await b.stop()
        lost = [await store.call(_finish, sync, n) for n in (1, 2, 3)]  # run with [mqtt] enabled = false
        await (ret := _retention(store, tmp_path, clock, mqtt_results=False)).run_once()
        clock.t += timedelta(days=40)
        caplog.set_level(logging.WARNING, logger="cellctl.service.retention")
        assert (await ret.run_once()).cycles_deleted == 3
        newer = await store.call(_finish, sync, 4)
        with running_broker(tmp_path) as broker:
            cfg = publisher_config(broker.port)
            t = CellTopics(cfg.isa95)
            with subscribed(broker.port, t.everything) as sub:  # [mqtt] enabled again
                outbox = Outbox(store, cfg.max_messages)
                await (bridge := _bridge(store, outbox)).start()
                pub = MqttPublisher(cfg, t, outbox)
                pub.start()
                await asyncio.to_thread(sub.wait_count, t.dropped, 1, 15.0)
                await asyncio.to_thread(sub.wait_count, t.result, 1, 15.0)
                await bridge.stop()
                await pub.stop()
        report = sub.on(t.dropped)[0].json()
        published = [m.json()["cycle_id"] for m in sub.on(t.result)]
        audit = [e for e in await store.audit_entries() if e.action == "retention.prune_cycles"]
    finally:
        await store.close()
    assert published == [newer]  # the pruned ones cannot be published any more ...
    assert report["dropped_results"] == len(lost) and report["dropped"] >= len(lost)  # ... so the plant is told
    assert audit[0].params["unpublished_results"] == len(lost)
    assert any("never queued" in r.getMessage() and "3" in r.getMessage() for r in caplog.records)
