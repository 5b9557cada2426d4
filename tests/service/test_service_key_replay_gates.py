"""A repeated idempotency key gets its cycle back, never a refusal: the requester (a PLC after its own restart, a REST
client retrying) asks what became of its request, and the gates that hold back a new cycle (the cell out of Execute,
the recipe not taught now) must not hide the answer. A new key meets the gates as before. Peer: the REST API (httpx)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_test_support import (
    AUTH,
    api_client,
    back_to_execute,
    _command,
    running_service,
    sim_config,
    to_execute,
)

pytestmark = pytest.mark.timeout(180)


async def _post(client: httpx.AsyncClient, key: str, part_id: str) -> httpx.Response:
    return await client.post("/cycle?wait=true&timeout_s=120", json={"recipe": "side-window", "part_id": part_id},
                             headers={**AUTH, "Idempotency-Key": key})  # fmt: skip


async def test_a_repeated_key_gets_its_cycle_back_whatever_the_gates_say_now(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        await to_execute(client)
        first: dict[str, Any] = (await _post(client, "r-1", "R-1")).json()
        assert first["state"] == "done", first

        # The recipe's teaching withdrawn since (as while it is taught again): a new key is refused, the old one answered.
        calibration = service.orchestrator.calibration
        monkeypatch.setattr(calibration, "untaught", lambda recipe: f"recipe {recipe} is not taught: teach it")
        refused = await _post(client, "r-2", "R-2")
        assert refused.status_code == 409 and "not taught" in refused.text
        again = await _post(client, "r-1", "R-1")
        assert again.status_code == 200 and again.json()["id"] == first["id"] and again.json()["state"] == "done"
        monkeypatch.undo()

        # The cell stopped: the same again.
        assert (await client.post("/commands/stop", headers=AUTH)).status_code == 200
        refused = await _post(client, "r-3", "R-3")
        assert refused.status_code == 409 and "not EXECUTE" in refused.text
        again = await _post(client, "r-1", "R-1")
        assert again.status_code == 200 and again.json()["id"] == first["id"] and again.json()["state"] == "done"


async def test_a_request_stored_as_the_cell_stops_is_dropped_and_never_starts_by_itself(tmp_path: Path) -> None:
    # The request passed the Execute check, and a Stop came while it was being stored: it must end at once, not wait
    # in the queue and start on its own once the cell is back in Execute, long after its requester gave up.
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        await to_execute(client)
        orch = service.orchestrator
        store_it = orch.store.submit_cycle

        async def stop_meanwhile(*args: Any, **kw: Any) -> Any:
            assert await _command(client, "stop") == "STOPPED"
            await asyncio.sleep(0.2)  # the stop's events handled too, before the request is stored
            return await store_it(*args, **kw)

        orch.store.submit_cycle = stop_meanwhile  # type: ignore[method-assign]
        r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "S-1"},
                              headers={**AUTH, "Idempotency-Key": "s-1"})  # fmt: skip
        orch.store.submit_cycle = store_it  # type: ignore[method-assign]
        assert r.status_code in (200, 201, 202), r.text
        cid = r.json()["cycle_id"]
        await back_to_execute(client)  # back in Execute: the dropped request must not run now
        again = await _post(client, "s-2", "S-2")
        assert again.json()["state"] == "done"
        dropped = (await client.get(f"/cycles/{cid}")).json()
        assert dropped["state"] == "failed" and "before it began" in dropped["error"], dropped
        assert dropped["steps"] == [] and dropped["started_at"] is None
