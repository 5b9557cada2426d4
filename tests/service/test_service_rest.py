"""The REST API over the real simulated cell: idempotent cycles, refusals that name the field."""

from __future__ import annotations

from pathlib import Path

import pytest
from service_test_support import AUTH, api_client, running_service, to_execute


async def test_the_same_idempotency_key_twice_gives_one_cycle(tmp_path: Path) -> None:
    async with running_service(tmp_path) as service, api_client(service) as client:
        await to_execute(client)
        body = {"recipe": "side-window", "part_id": "P-1"}
        first = await client.post("/cycle?wait=true&timeout_s=60", json=body, headers={**AUTH, "Idempotency-Key": "k-1"})
        assert first.status_code == 200, first.text
        assert first.json()["state"] == "done"
        again = await client.post("/cycle", json=body, headers={**AUTH, "Idempotency-Key": "k-1"})
        assert again.status_code == 202
        assert again.json()["cycle_id"] == first.json()["id"] and again.json()["created"] is False
        cycles = (await client.get("/cycles")).json()
        assert [c["id"] for c in cycles] == [first.json()["id"]]
        # The same key for another request is a conflict, not a second cycle.
        other = await client.post("/cycle", json={**body, "part_id": "P-2"}, headers={**AUTH, "Idempotency-Key": "k-1"})
        assert other.status_code == 422 and "part_id" in other.json()["detail"]
        # The record holds every step, the images and the true error.
        rec = (await client.get(f"/cycles/{first.json()['id']}")).json()
        steps = [s["step"] for s in rec["steps"]]
        assert steps[:3] == ["calibrate", "align", "shoot"] and steps[-2:] == ["install", "inspect"]
        assert all(s["ok"] for s in rec["steps"])
        assert set(rec["true_error"]) == {"dx_mm", "dy_mm", "dz_mm", "drx_deg", "dry_deg", "drz_deg"}
        png = await client.get(rec["images"][0]["url"])
        assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    ("headers", "body", "status", "names"),
    [
        ({}, {"recipe": "side-window", "part_id": "P"}, 401, ["Bearer"]),
        (AUTH, {"recipe": "side-window", "part_id": "P"}, 422, ["Idempotency-Key"]),
        ({**AUTH, "Idempotency-Key": "k"}, {"recipe": "side-window"}, 422, ["part_id"]),
        ({**AUTH, "Idempotency-Key": "k"}, {"recipe": "side-window", "part_id": ""}, 422, ["part_id"]),
        ({**AUTH, "Idempotency-Key": "k"}, {"recipe": "rear-door", "part_id": "P"}, 422, ["recipe", "side-window"]),
        ({**AUTH, "Idempotency-Key": "k"}, {"recipe": "side-window", "part_id": "P", "colour": "red"}, 422, ["colour"]),
    ],
)
async def test_bad_requests_get_4xx_naming_the_field(
    tmp_path: Path, headers: dict, body: dict, status: int, names: list[str]
) -> None:
    async with running_service(tmp_path) as service, api_client(service) as client:
        r = await client.post("/cycle", json=body, headers=headers)
        assert r.status_code == status, r.text
        for name in names:
            assert name in r.json()["detail"]
        assert (await client.get("/cycles")).json() == []


async def test_a_cycle_or_command_the_state_forbids_gets_409(tmp_path: Path) -> None:
    async with running_service(tmp_path) as service, api_client(service) as client:
        # The service starts Aborted after every start: no cycle, and Start is not in the table there.
        r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "P"}, headers={**AUTH, "Idempotency-Key": "x"})
        assert r.status_code == 409 and "ABORTED" in r.json()["detail"]
        r = await client.post("/commands/start", headers=AUTH)
        assert r.status_code == 409 and "Start refused in Aborted" in r.json()["detail"]
        assert "clear" in (await client.get("/status")).json()["allowed_commands"]
        r = await client.post("/commands/jump", headers=AUTH)
        assert r.status_code == 422 and "name" in r.json()["detail"]


async def test_docs_metrics_and_health_are_served_locally(tmp_path: Path) -> None:
    async with running_service(tmp_path) as service, api_client(service) as client:
        docs = await client.get("/docs")
        assert docs.status_code == 200 and "/static/swagger-ui/swagger-ui-bundle.js" in docs.text
        assert "http" not in docs.text.replace("http://cell", "").split("swagger-ui-bundle.js")[0].split("<script")[-1]
        assert (await client.get("/static/swagger-ui/swagger-ui-bundle.js")).status_code == 200
        assert "/cycle" in (await client.get("/openapi.json")).json()["paths"]
        metrics = (await client.get("/metrics")).text
        assert "cellctl_packml_state 9" in metrics and 'cellctl_cycles{state="done"} 0' in metrics
        assert (await client.get("/health")).json()["store"]["journal_mode"] == "wal"
