"""``cellctl_cycle_time_seconds`` counts every cycle finished while the service runs, also after the
wall clock was stepped back (NTP correcting a fast clock), and none finished before it started.
Read with prometheus_client's own parser."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from prometheus_client.parser import text_string_to_metric_families

from cellctl.api.metrics import CellMetrics
from cellctl.store import AsyncCellStore, CellStore, CycleRequest


class Clock:
    def __init__(self) -> None:
        self.t = datetime.now(timezone.utc) - timedelta(days=1)

    def __call__(self) -> datetime:
        return self.t


def _finish(store: CellStore, n: int, clock: Clock) -> None:
    clock.t += timedelta(minutes=2)
    cid = store.submit_cycle(CycleRequest("side-window", f"P-{n}"), scope="t", key=f"k{n}", actor="t").cycle.id
    store.start_cycle(cid)
    store.complete_cycle(cid, result={"ok": True, "cycle_time_s": 40.0})


def _orchestrator(store: AsyncCellStore) -> Any:
    status = {"state_id": 6, "mode_id": 1, "devices": {}}
    return SimpleNamespace(status=lambda: status, store=store, alarms=SimpleNamespace(current=list))


async def _done_count(metrics: CellMetrics) -> float:
    families = {f.name: f for f in text_string_to_metric_families((await metrics.exposition()).decode())}
    samples = families["cellctl_cycle_time_seconds"].samples
    return next(s.value for s in samples if s.name.endswith("_count") and s.labels["outcome"] == "done")


async def test_cycles_after_a_backward_clock_step_are_counted(tmp_path: Path) -> None:
    clock = Clock()
    store = await AsyncCellStore.open(tmp_path / "cell.db", clock=clock, synchronous="NORMAL")
    try:
        for n in range(3):  # before this service started: never in its histogram
            await store.call(_finish, store._store, n, clock)
        clock.t = datetime.now(timezone.utc)  # the service starts (its wall clock an hour fast)
        metrics = CellMetrics(_orchestrator(store))
        assert await _done_count(metrics) == 0
        await store.call(_finish, store._store, 3, clock)
        assert await _done_count(metrics) == 1
        clock.t -= timedelta(hours=1)  # NTP steps the clock back an hour
        for n in range(4, 8):
            await store.call(_finish, store._store, n, clock)
        assert await _done_count(metrics) == 5  # 1 + 4 finished since the start
    finally:
        await store.close()
