"""The cell's figures for Prometheus, in prometheus_client's own exposition format.

Each app has its own :class:`CellMetrics`: a ``CollectorRegistry`` of its own (never the global
one, so several services in one process do not clash) holding one collector that reads the cell
when it is scraped. The cycle counts come from the database, which is read asynchronously, so
:meth:`CellMetrics.exposition` reads them first and then renders the registry at once.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import GaugeMetricFamily, Metric

from cellctl.cell.orchestrator import CellOrchestrator
from cellctl.store import CycleState

__all__ = ["CONTENT_TYPE_LATEST", "CellMetrics"]


class CellMetrics:
    """A collector of the cell's gauges (PackML state and mode, cycles, alarms, devices) and its registry."""

    def __init__(self, orch: CellOrchestrator) -> None:
        self._orch = orch
        self._cycle_counts: dict[CycleState, int] = {}
        self.registry = CollectorRegistry()
        self.registry.register(self)

    async def exposition(self) -> bytes:
        """The text a scrape gets (content type :data:`CONTENT_TYPE_LATEST`)."""
        self._cycle_counts = await self._orch.store.cycle_counts()
        return generate_latest(self.registry)  # no await in between: this scrape's counts are the ones rendered

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
        up = GaugeMetricFamily("cellctl_device_up", "1 while the watchdog sees the device", labels=["device"])
        age = GaugeMetricFamily("cellctl_device_heartbeat_age_seconds", "Time since the device last answered", labels=["device"])
        for name, d in st["devices"].items():
            up.add_metric([name], 1.0 if d["link"] == "up" else 0.0)
            if d["heartbeat_age_s"] is not None:
                age.add_metric([name], d["heartbeat_age_s"])
        yield up
        yield age
        yield _gauge("cellctl_scrape_timestamp_seconds", "Wall time of this scrape", time.time())


def _gauge(name: str, help_text: str, value: float) -> GaugeMetricFamily:
    return GaugeMetricFamily(name, help_text, value=value)
