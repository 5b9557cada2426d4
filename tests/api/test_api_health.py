"""Issue 20, /health: 200 with the details when the cell can work, 503 when a device link or the PLC link
is down, the store does not answer or the service stops; /health/live answers while the process serves."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import AUTH, api_client, running_service, sim_config

from cellctl.api.health import plc_problem

pytestmark = pytest.mark.timeout(120)
FAST_WATCHDOG = {"period_s": 0.2, "timeout_s": 0.15, "miss_threshold": 2}


async def _health_becomes(client: httpx.AsyncClient, code: int, timeout_s: float = 20.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while True:
        r = await client.get("/health")
        if r.status_code == code:
            return dict(r.json())
        assert time.monotonic() < deadline, f"/health stayed {r.status_code}: {r.text}"
        await asyncio.sleep(0.05)


async def test_a_healthy_cell_answers_200_with_the_details(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        r = await client.get("/health")
        assert r.status_code == 200
        assert r.json() == {"ok": True, "devices_lost": [], "problems": [], "store": {"journal_mode": "wal"}}
        assert (await client.get("/health/live")).json() == {"ok": True}


async def test_a_device_down_answers_503_and_200_again_once_it_answers(tmp_path: Path) -> None:
    config = sim_config(plc={"enabled": False}, **{"alarms.watchdog": FAST_WATCHDOG})
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        laser = service.extras["fakes"]["laser"]  # type: ignore[index]
        laser.silence(count=None)
        body = await _health_becomes(client, 503)
        assert body["ok"] is False and body["devices_lost"] == ["laser"]
        assert any("laser" in p for p in body["problems"]), body
        live = await client.get("/health/live")
        assert live.status_code == 200  # liveness: the process still serves; no restart for a device fault
        laser.speak()
        body = await _health_becomes(client, 200)
        assert body["devices_lost"] == [] and body["problems"] == []


@contextlib.asynccontextmanager
async def _plc(service: Any) -> AsyncIterator[PlcClient]:
    """A PLC connected to the service's Modbus server (its heartbeat started and stopped by the test)."""
    client = AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1)
    assert await client.connect()
    plc = PlcClient(client, service.config.plc.float_word_order, unit_id=service.config.plc.unit_id)
    try:
        yield plc
    finally:
        await plc.stop_heartbeat()
        client.close()


async def test_the_plc_link_lost_answers_503_with_the_heartbeat_alarm_on(tmp_path: Path) -> None:
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005, "heartbeat_alarm": True, "heartbeat_timeout_s": 0.5})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client, _plc(service) as plc:
        plc.start_heartbeat(0.05)
        body = await _health_becomes(client, 200)
        await _eventually(lambda: _plc_state(client, "up"))
        await plc.stop_heartbeat()  # the PLC stays connected and stops beating
        body = await _health_becomes(client, 503)
        assert body["plc"] == "lost" and any("PLC link is lost" in p for p in body["problems"]), body
        plc.start_heartbeat(0.05)  # it beats again: healthy again
        body = await _health_becomes(client, 200)
        assert body["plc"] == "up" and body["problems"] == []


async def test_a_plc_that_never_beats_is_waiting_then_lost(tmp_path: Path) -> None:
    """Waiting (no heartbeat yet) is healthy; after heartbeat_timeout_s the interface reports it lost."""
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005, "heartbeat_alarm": True, "heartbeat_timeout_s": 2.0})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        first = await client.get("/health")
        assert first.status_code == 200 and first.json()["plc"] == "waiting", first.text
        body = await _health_becomes(client, 503)
        assert body["plc"] == "lost", body


async def test_a_lost_plc_without_the_heartbeat_alarm_is_shown_but_not_down(tmp_path: Path) -> None:
    """The simulated cell's own setting: it runs without a PLC, so its PLC link never makes it unhealthy."""
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005, "heartbeat_alarm": False, "heartbeat_timeout_s": 0.3})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client, _plc(service) as plc:
        plc.start_heartbeat(0.05)
        await _eventually(lambda: _plc_state(client, "up"))
        await plc.stop_heartbeat()
        await _eventually(lambda: _plc_state(client, "lost"))
        r = await client.get("/health")
        assert r.status_code == 200 and r.json()["plc"] == "lost"


def test_only_a_lost_plc_link_with_the_alarm_on_counts() -> None:
    assert plc_problem({"link": "waiting"}, counts=True) is None
    assert plc_problem({"link": "up"}, counts=True) is None
    assert plc_problem(None, counts=True) is None
    assert plc_problem({"link": "lost", "silent_for_s": 4.2}, counts=False) is None
    assert plc_problem({"link": "lost", "silent_for_s": 4.2}, counts=True) == "the PLC link is lost (no heartbeat for 4.2 s)"


async def test_a_stopping_service_or_a_store_that_fails_answers_503(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        real_info = service.store.info

        async def broken() -> Any:
            raise OSError(f"disk I/O error at {tmp_path}")

        service.store.info = broken  # type: ignore[method-assign]
        r = await client.get("/health")
        assert r.status_code == 503 and "store" not in r.json()
        assert r.json()["problems"] == ["the store does not answer (OSError)"]  # never the path
        service.store.info = real_info  # type: ignore[method-assign]
        assert (await client.get("/health")).status_code == 200
        service.orchestrator.events.close()  # what SIGTERM does first
        r = await client.get("/health")
        assert r.status_code == 503 and r.json()["problems"] == ["the service is stopping"]
        assert (await client.get("/health/live")).status_code == 200


async def test_closed_reads_give_an_anonymous_caller_the_status_code_and_ok_alone(tmp_path: Path) -> None:
    config = sim_config(plc={"enabled": False}, api={"open_reads": False})
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        service.orchestrator.events.close()
        r = await client.get("/health")
        assert r.status_code == 503 and r.json() == {"ok": False}
        detailed = await client.get("/health", headers=AUTH)
        assert detailed.status_code == 503 and detailed.json()["problems"] == ["the service is stopping"]


async def _plc_state(client: httpx.AsyncClient, state: str) -> bool:
    return bool((await client.get("/health")).json().get("plc") == state)


async def _eventually(check: Callable[[], Awaitable[bool]], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not await check():
        assert time.monotonic() < deadline, "not in time"
        await asyncio.sleep(0.02)
