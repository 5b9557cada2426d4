"""``cellctl_cycle_time_seconds`` observes the cycle time of cycles that ran, as their records give it (the cell's
clock); a queued cycle a Stop dropped never began, has no cycle time and is not observed (it was, with its wait in the
queue in host seconds). Read with prometheus_client's own parser; the records are the store's."""

from __future__ import annotations

import asyncio
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from prometheus_client.parser import text_string_to_metric_families

from cellctl.api.metrics import CellMetrics
from cellctl.store import AsyncCellStore, CellStore, CycleRequest


def _ran(store: CellStore, n: int, seconds: float) -> None:
    cid = store.submit_cycle(CycleRequest("side-window", f"P-{n}"), scope="t", key=f"k{n}", actor="t").cycle.id
    store.start_cycle(cid)
    store.fail_cycle(cid, error="laser silent", result={"error_code": 1301, "cycle_time_s": seconds})


def _dropped(store: CellStore, n: int) -> None:
    cid = store.submit_cycle(CycleRequest("side-window", f"P-{n}"), scope="t", key=f"k{n}", actor="t").cycle.id
    store.fail_cycle(cid, error="not started: the cell went to stopping before it began", result={"error_code": 1010})


def _orchestrator(store: AsyncCellStore) -> Any:
    status = {"state_id": 6, "mode_id": 1, "devices": {}}
    return SimpleNamespace(status=lambda: status, store=store, alarms=SimpleNamespace(current=list))


async def _failed(metrics: CellMetrics) -> tuple[float, float]:
    families = {f.name: f for f in text_string_to_metric_families((await metrics.exposition()).decode())}
    samples = {s.name: s.value for s in families["cellctl_cycle_time_seconds"].samples if s.labels.get("outcome") == "failed"}
    return samples["cellctl_cycle_time_seconds_count"], samples["cellctl_cycle_time_seconds_sum"]


async def test_a_cycle_dropped_from_the_queue_is_not_a_cycle_time(tmp_path: Path) -> None:
    store = await AsyncCellStore.open(tmp_path / "cell.db", synchronous="NORMAL")
    try:
        metrics = CellMetrics(_orchestrator(store))
        assert await _failed(metrics) == (0, 0)
        await store.call(_ran, store._store, 1, 12.5)
        await store.call(_dropped, store._store, 2)
        await store.call(_ran, store._store, 3, 20.0)
        assert await _failed(metrics) == (2, 32.5)  # the two that ran, their recorded times
        await store.call(_dropped, store._store, 4)
        assert await _failed(metrics) == (2, 32.5)
    finally:
        await store.close()


async def test_scrapes_at_once_count_each_cycle_once(tmp_path: Path) -> None:
    """Two Prometheus servers of an HA pair (and a person's curl) scrape at the same time: each cycle is one count."""
    store = await AsyncCellStore.open(tmp_path / "cell.db", synchronous="NORMAL")
    try:
        metrics = CellMetrics(_orchestrator(store))
        assert await _failed(metrics) == (0, 0)
        for n in range(5):
            await store.call(_ran, store._store, n, 10.0)
        scraped = await asyncio.gather(*(_failed(metrics) for _ in range(8)))
        assert set(scraped) == {(5, 50.0)}, scraped
    finally:
        await store.close()
