"""REST roles: a viewer's token reads, an operator's runs production and changes the unit mode (as on OPC UA),
only an engineer's resets the SPC loop or runs (and answers, cancels) calibration jobs; a lower role gets 403 naming both roles."""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import httpx
from service_test_support import api_client, running_service, sim_config

VIEWER, OPERATOR, ENGINEER = "viewer-Tq7wLp2xZr9k", "line-Mb4nVc8sHd1j", "commissioning-Fg6yRt3uJk0e"
TOKENS = [
    {"name": "scada", "token": VIEWER, "role": "viewer"},
    {"name": "line", "token": OPERATOR, "role": "operator"},
    {"name": "integrator", "token": ENGINEER, "role": "engineer"},
]


def auth(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


class CountedBody:
    """A request body handed out in chunks, counting how many the server pulled."""

    def __init__(self) -> None:
        self.pulled = 0

    async def __aiter__(self) -> AsyncIterator[bytes]:
        for _ in range(2):
            self.pulled += 1
            yield b" " * 100


def forbidden(r: httpx.Response, route: str, needed: str, name: str, role: str) -> bool:
    """A 403 whose detail names the route, the role it needs, the token and the token's role."""
    detail = r.json().get("detail", "") if r.headers.get("content-type", "").startswith("application/json") else ""
    return r.status_code == 403 and detail.startswith(f"{route} needs the {needed} role; token '{name}' is {role}:") and (
        "[api].tokens" in detail)


async def _settled(client: httpx.AsyncClient) -> str:
    for _ in range(300):
        state = str((await client.get("/status")).json()["state"])
        if not state.endswith("ING"):
            return state
        await asyncio.sleep(0.01)
    return state


async def _command(client: httpx.AsyncClient, cmd: str, token: str) -> tuple[int, str]:
    r = await client.post(f"/commands/{cmd}", headers=auth(token))
    return r.status_code, await _settled(client)


async def test_each_role_gets_its_routes_and_403_beyond_them(tmp_path: Path) -> None:
    config = sim_config(plc={"enabled": False}, api={"tokens": TOKENS})
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        # viewer: reads, nothing else (a mutating route's body is not even read)
        assert (await client.get("/status", headers=auth(VIEWER))).status_code == 200
        body = CountedBody()
        r = await client.post("/cycle", content=body, headers={**auth(VIEWER), "Idempotency-Key": "k-v", "Content-Type": "application/json"})
        assert forbidden(r, "POST /cycle", "operator", "scada", "viewer"), r.text
        assert "use an operator's or an engineer's token" in r.json()["detail"] and body.pulled == 0
        r = await client.post("/commands/clear", headers=auth(VIEWER))
        assert forbidden(r, "POST /commands/{name}", "operator", "scada", "viewer"), r.text
        r = await client.post("/alarms/acknowledge-all", headers=auth(VIEWER))
        assert forbidden(r, "POST /alarms/acknowledge-all", "operator", "scada", "viewer"), r.text

        # operator: acknowledges, commands, the unit mode, but neither the SPC loop nor a job
        assert (await client.post("/alarms/acknowledge-all", headers=auth(OPERATOR))).status_code == 200
        assert await _command(client, "clear", OPERATOR) == (200, "STOPPED")
        r = await client.post("/mode/maintenance", headers=auth(VIEWER))
        assert forbidden(r, "POST /mode/{name}", "operator", "scada", "viewer"), r.text
        r = await client.post("/mode/maintenance", headers=auth(OPERATOR))
        assert r.status_code == 200 and r.json()["mode"] == "MAINTENANCE", r.text
        assert (await client.post("/mode/production", headers=auth(OPERATOR))).status_code == 200
        r = await client.post("/spc/reset", headers=auth(OPERATOR))
        assert forbidden(r, "POST /spc/reset", "engineer", "line", "operator"), r.text
        assert "use an engineer's token" in r.json()["detail"]
        body = CountedBody()
        r = await client.post("/jobs", content=body, headers={**auth(OPERATOR), "Content-Type": "application/json"})
        assert forbidden(r, "POST /jobs", "engineer", "line", "operator"), r.text
        assert body.pulled == 0
        assert (await client.get("/status")).json()["mode"] == "PRODUCTION"

        # engineer: SPC reset, a calibration job; the operator may neither answer nor cancel it
        assert (await client.post("/spc/reset", headers=auth(ENGINEER))).status_code == 200
        r = await client.post("/jobs", json={"procedure": "camera"}, headers=auth(ENGINEER))
        assert r.status_code == 201, r.text
        job_id = r.json()["id"]
        r = await client.post(f"/jobs/{job_id}/prompts/1", json={"action": "confirm"}, headers=auth(OPERATOR))
        assert forbidden(r, "POST /jobs/{job_id}/prompts/{prompt_id}", "engineer", "line", "operator"), r.text
        r = await client.post(f"/jobs/{job_id}/cancel", headers=auth(OPERATOR))
        assert forbidden(r, "POST /jobs/{job_id}/cancel", "engineer", "line", "operator"), r.text
        r = await client.post(f"/jobs/{job_id}/cancel", headers=auth(ENGINEER))
        assert r.status_code == 200, r.text

        # operator: production (a cycle, queued)
        assert await _wait_job_over(client, job_id) == "cancelled"
        for cmd in ("reset", "start"):
            assert (await _command(client, cmd, OPERATOR))[0] == 200
        r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "P-1"},
                              headers={**auth(OPERATOR), "Idempotency-Key": str(uuid.uuid4())})  # fmt: skip
        assert r.status_code == 202, r.text

        audit = await service.store.audit_entries(limit=1000)
        actors = {(a.action, a.actor) for a in audit}
        assert {("spc.reset", "integrator"), ("job.start", "integrator"), ("job.cancel", "integrator"),
                ("alarm.acknowledge_all", "line")} <= actors, actors  # fmt: skip
        assert not any(a.actor == "scada" for a in audit)


async def _wait_job_over(client: httpx.AsyncClient, job_id: int) -> str:
    """The job's state once it has finished (the store's finished states)."""
    for _ in range(500):
        state = str((await client.get(f"/jobs/{job_id}")).json()["state"])
        if state in ("done", "refused", "failed", "cancelled", "interrupted"):
            return state
        await asyncio.sleep(0.01)
    return state


async def test_closed_reads_take_any_role(tmp_path: Path) -> None:
    config = sim_config(plc={"enabled": False}, api={"tokens": TOKENS, "open_reads": False})
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        assert (await client.get("/status")).status_code == 401
        for token in (VIEWER, OPERATOR, ENGINEER):
            assert (await client.get("/status", headers=auth(token))).status_code == 200
            assert (await client.post("/jobs/plan", json={"procedure": "camera"}, headers=auth(token))).status_code == 200


def test_the_openapi_document_names_the_403_of_each_route_that_needs_a_role() -> None:
    from unittest import mock

    from cellctl.api.app import create_app

    config = sim_config(plc={"enabled": False}, api={"tokens": TOKENS})
    doc: dict[str, Any] = create_app(mock.MagicMock(name="orchestrator"), config.api, mock.MagicMock(name="jobs")).openapi()
    expected = {
        ("post", "/cycle"): "operator", ("post", "/commands/{name}"): "operator",
        ("post", "/alarms/{uid}/acknowledge"): "operator", ("post", "/alarms/acknowledge-all"): "operator",
        ("post", "/mode/{name}"): "operator", ("post", "/spc/reset"): "engineer", ("post", "/jobs"): "engineer",
        ("post", "/jobs/{job_id}/cancel"): "engineer", ("post", "/jobs/{job_id}/prompts/{prompt_id}"): "engineer",
    }  # fmt: skip
    seen = {}
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            if "403" in op["responses"]:
                seen[(method, path)] = op["responses"]["403"]
    assert set(seen) == set(expected)
    for key, response in seen.items():
        assert f"needs the {expected[key]} role" in response["description"], key
        assert response["content"]["application/json"]["schema"] == {"$ref": "#/components/schemas/ErrorBody"}
