"""A job asked for while the cell is in Execute: the refusal says Stop first, and that Stop ends the cycle in progress.

The simulated cell's real composition over its REST API; the warning is checked against what a Stop does to a
running cycle (the cycle's own record).
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import httpx
from service_test_support import AUTH, api_client, running_service, sim_config, slow_moves, to_execute


async def _cycle_state(client: httpx.AsyncClient, cycle_id: int, *states: str, timeout_s: float = 20.0) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        state = (await client.get(f"/cycles/{cycle_id}")).json()["state"]
        if state in states:
            return str(state)
        await asyncio.sleep(0.02)
    raise AssertionError(f"cycle {cycle_id} never reached {states}")


async def test_the_refusal_in_execute_warns_that_stop_ends_the_running_cycle(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        await to_execute(client)
        slow_moves(service, 1000.0)  # the twin's moves in real time: the cycle is still running when Stop comes
        r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "P-1"}, headers={**AUTH, "Idempotency-Key": "k1"})
        assert r.status_code == 202, r.text
        cycle_id = r.json()["cycle_id"]
        await _cycle_state(client, cycle_id, "running")
        r = await client.post("/jobs", json={"procedure": "laser"}, headers=AUTH)
        assert r.status_code == 409, r.text
        detail = r.json()["detail"]
        assert "EXECUTE" in detail and "send Stop" in detail and "Stop ends a running" in detail, detail
        assert "once the cycle in progress has ended" in detail, detail
        # The warning is true: a Stop now ends the running cycle, unfinished.
        assert (await client.post("/commands/stop", headers=AUTH)).status_code == 200
        assert await _cycle_state(client, cycle_id, "failed", "interrupted", "done") != "done"
