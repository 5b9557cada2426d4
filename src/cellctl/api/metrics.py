"""The cell's figures for Prometheus, in prometheus_client's own exposition format.

Each app has its own :class:`CellMetrics`: a ``CollectorRegistry`` of its own (never the global
one, so several services in one process do not clash) holding one collector that reads the cell
when it is scraped, the cycle-time histogram, and prometheus_client's process and platform
collectors (``process_*``: CPU, resident memory, open files; ``python_info``). The cycle counts
and the cycles finished since the last scrape come from the database, which is read
asynchronously, so :meth:`CellMetrics.exposition` reads them first and then renders the registry
at once.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import platform
import time
from collections.abc import Iterator
from typing import Any

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Histogram,
    PlatformCollector,
    ProcessCollector,
    generate_latest,
)
from prometheus_client.core import GaugeMetricFamily, Metric

import cellctl
from cellctl.cell.orchestrator import CellOrchestrator
from cellctl.cell.watchdog import LinkState
from cellctl.store import CycleState
from cellctl.store.records import CycleRecord

CYCLE_TIME_BUCKETS_S = (0.5, 1.0, 2.0, 3.0, 5.0, 7.5, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0)
"""Buckets of ``cellctl_cycle_time_seconds``: a simulated cycle takes about a second, a real one 10-40 s."""
CYCLE_PAGE = 200
log = logging.getLogger(__name__)

__all__ = ["CONTENT_TYPE_LATEST", "CellMetrics"]


class CellMetrics:
    """A collector of the cell's gauges (PackML state and mode, cycles, alarms, devices) and its registry."""

    def __init__(self, orch: CellOrchestrator) -> None:
        self._orch = orch
        self._cycle_counts: dict[CycleState, int] = {}
        # "Since the service started" by cycle id, not wall time (a clock stepped back must not hide cycles):
        # the newest cycle now is the mark; the histogram counts the cycles after it.
        self._seen_id: int | None = None  # the newest cycle already in the histogram (or before the start)
        self._mark: asyncio.Task[int] | None = None
        self._scraping = asyncio.Lock()  # scrapes at once (an HA pair of Prometheus servers) count each cycle once
        with contextlib.suppress(RuntimeError):  # no running loop: the first scrape takes the mark
            self._mark = asyncio.get_running_loop().create_task(self._newest_id())
            self._mark.add_done_callback(lambda t: t.cancelled() or t.exception())  # its error is the first scrape's
        self.registry = CollectorRegistry()
        self.registry.register(self)
        self.cycle_time = Histogram(
            "cellctl_cycle_time_seconds",
            "Cycle time of the cycles finished (done or failed) since the service started, from their records: the robot "
            "time on the cell's clock; a cycle that never began (dropped from the queue) is not counted",
            labelnames=["outcome"], buckets=CYCLE_TIME_BUCKETS_S, registry=self.registry,
        )  # fmt: skip
        for outcome in (CycleState.DONE, CycleState.FAILED):
            self.cycle_time.labels(outcome=outcome.value)  # both series from the first scrape, at 0
        ProcessCollector(registry=self.registry)
        PlatformCollector(registry=self.registry)

    async def exposition(self) -> bytes:
        """The text a scrape gets (content type :data:`CONTENT_TYPE_LATEST`)."""
        async with self._scraping:
            self._cycle_counts = await self._orch.store.cycle_counts()
            await self._observe_finished_cycles()
            return generate_latest(self.registry)  # no await in between: this scrape's counts are the ones rendered

    async def _observe_finished_cycles(self) -> None:
        """Put the cycles finished since the last scrape into the histogram (newest first, a page at a time).

        Cycles run one at a time in id order, so every finished cycle newer than the last one seen
        is new; a cycle older than the newest one at this service's start is never counted.
        """
        seen = self._seen_id = await self._start_mark() if self._seen_id is None else self._seen_id
        fresh: list[CycleRecord] = []
        before: int | None = None
        while True:
            page = await self._orch.store.cycles(limit=CYCLE_PAGE, before_id=before)
            new = [r for r in page if r.id > seen]
            fresh += [r for r in new if r.finished_at is not None and r.state in (CycleState.DONE, CycleState.FAILED)
                      and r.started_at is not None]  # one dropped from the queue (a Stop) never ran: no cycle time
            if len(new) < CYCLE_PAGE:  # reached what was seen (or the start): no older page has anything new
                break
            before = page[-1].id
        for rec in sorted(fresh, key=lambda r: r.id):
            self.cycle_time.labels(outcome=rec.state.value).observe(_cycle_seconds(rec))
            self._seen_id = rec.id

    async def _newest_id(self) -> int:
        page = await self._orch.store.cycles(limit=1)
        return page[0].id if page else 0

    async def _start_mark(self) -> int:
        """The newest cycle id when this service started (read at once then; at the first scrape if that failed)."""
        mark, self._mark = self._mark, None
        if mark is not None:
            try:
                return await mark
            except Exception as err:  # noqa: BLE001 - the store was not readable then: count from now on
                log.warning("metrics: the newest cycle at start could not be read (%s); the histogram counts from now", err)
        return await self._newest_id()

    def collect(self) -> Iterator[Metric]:
        """The gauges as of now (prometheus_client calls this while it renders the registry)."""
        st = self._orch.status()
        yield _gauge("cellctl_packml_state", "PackML StateCurrent (PackTags integer)", st["state_id"])
        yield _gauge("cellctl_unit_mode", "PackML UnitModeCurrent", st["mode_id"])
        cycles = GaugeMetricFamily("cellctl_cycles", "Cycles in the store by state", labels=["state"])
        for s in CycleState:
            cycles.add_metric([s.value], self._cycle_counts.get(s, 0))
        yield cycles
        yield _gauge("cellctl_alarms_active", "Active alarms", sum(a.active for a in self._orch.alarms.current()))
        yield from _device_gauges(st["devices"])
        yield _gauge("cellctl_scrape_timestamp_seconds", "Wall time of this scrape", time.time())
        build = GaugeMetricFamily("cellctl_build_info", "The running cellctl: its version (always 1)", labels=["version", "python_version"])
        build.add_metric([cellctl.__version__, platform.python_version()], 1.0)
        yield build


def _device_gauges(devices: dict[str, dict[str, Any]]) -> Iterator[Metric]:
    """Up: 0 only once the watchdog lost the device, as /health judges; its link state as a label. Heartbeat age."""
    up = GaugeMetricFamily(
        "cellctl_device_up", "0 once the watchdog lost the device (as /health), else 1; state: unknown, up, degraded or lost",
        labels=["device", "state"],
    )  # fmt: skip
    age = GaugeMetricFamily("cellctl_device_heartbeat_age_seconds", "Time since the device last answered", labels=["device"])
    for name, d in devices.items():
        up.add_metric([name, d["link"]], 0.0 if d["link"] == LinkState.LOST.value else 1.0)
        if d["heartbeat_age_s"] is not None:
            age.add_metric([name], d["heartbeat_age_s"])
    yield from (up, age)


def _cycle_seconds(rec: CycleRecord) -> float:
    """The cycle's recorded time (its result's ``cycle_time_s``, the cell's clock), else its start to its finish."""
    recorded = (rec.result or {}).get("cycle_time_s")
    if isinstance(recorded, (int, float)):
        return float(recorded)
    start = rec.started_at or rec.created_at
    return max(0.0, ((rec.finished_at or start) - start).total_seconds())


def _gauge(name: str, help_text: str, value: float) -> GaugeMetricFamily:
    return GaugeMetricFamily(name, help_text, value=value)
