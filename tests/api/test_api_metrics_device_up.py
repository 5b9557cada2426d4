"""``cellctl_device_up`` agrees with /health: a device is down only once the watchdog lost it (not while
it is unknown before its first ping, nor while degraded); its link state is a label. Read
with prometheus_client's own parser."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any
from unittest import mock

from prometheus_client.parser import text_string_to_metric_families

from cellctl.api.health import judge
from cellctl.api.metrics import CellMetrics

LINKS = {"robot": "unknown", "camera": "up", "laser": "degraded", "plc_io": "lost"}


def _orchestrator() -> Any:
    """A cell whose devices are in each of the watchdog's link states."""
    devices = {name: {"link": link, "heartbeat_age_s": None, "round_trip_s": None} for name, link in LINKS.items()}
    status = {"state_id": 4, "mode_id": 1, "devices": devices, "links": {}}
    store = SimpleNamespace(
        cycle_counts=mock.AsyncMock(return_value={}), cycles=mock.AsyncMock(return_value=[]),
        info=mock.AsyncMock(return_value=SimpleNamespace(journal_mode="wal")),
    )  # fmt: skip
    return SimpleNamespace(
        status=lambda: status, store=store, alarms=SimpleNamespace(current=list),
        events=SimpleNamespace(closing=False), config=SimpleNamespace(plc=SimpleNamespace(enabled=False, heartbeat_alarm=False)),
    )  # fmt: skip


async def test_a_device_is_down_in_the_metrics_exactly_when_health_counts_it_lost() -> None:
    orch = _orchestrator()
    text = (await CellMetrics(orch).exposition()).decode()
    families = {f.name: f for f in text_string_to_metric_families(text)}
    up = {s.labels["device"]: s.value for s in families["cellctl_device_up"].samples}
    assert up == {"robot": 1.0, "camera": 1.0, "laser": 1.0, "plc_io": 0.0}
    lost = (await judge(orch)).devices_lost
    assert sorted(d for d, v in up.items() if v == 0.0) == lost == ["plc_io"]
    states = {s.labels["device"]: s.labels["state"] for s in families["cellctl_device_up"].samples}
    assert states == LINKS  # the watchdog's link state, as a label
