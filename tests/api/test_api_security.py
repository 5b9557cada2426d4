"""Issue 15, security: closed reads close /health's details and /metrics, no body is read before its
size and (on a mutating route) its token are checked, and a token file opens the API."""

from __future__ import annotations

import json
from collections.abc import AsyncIterator
from pathlib import Path

from service_test_support import AUTH, api_client, running_service, sim_config

from cellctl.config.api import DEFAULT_MAX_BODY_BYTES

CYCLE_HEADERS = {**AUTH, "Idempotency-Key": "k-1", "Content-Type": "application/json"}


class CountedBody:
    """A request body handed out in chunks, counting how many the server pulled."""

    def __init__(self, chunks: int, size: int) -> None:
        self.chunks, self.size, self.pulled = chunks, size, 0

    async def __aiter__(self) -> AsyncIterator[bytes]:  # httpx's ASGI transport pulls it as the app receives
        for _ in range(self.chunks):
            self.pulled += 1
            yield b" " * self.size


def test_the_default_body_limit_fits_the_apis_bodies() -> None:
    biggest = {"recipe": "r" * 64, "part_id": "p" * 64, "car_id": "c" * 64}  # CycleRequestBody at its field limits
    assert len(json.dumps(biggest)) * 20 < DEFAULT_MAX_BODY_BYTES <= 64 * 1024


async def test_closed_reads_leave_health_ok_open_and_the_rest_behind_the_token(tmp_path: Path) -> None:
    config = sim_config(plc={"enabled": False}, api={"open_reads": False})
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        anonymous = await client.get("/health")
        assert anonymous.status_code == 200 and anonymous.json() == {"ok": True}
        for path in ("/metrics", "/status", "/cycles", "/jobs"):
            r = await client.get(path)
            assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer", path
            assert "Bearer" in r.json()["detail"]
        details = await client.get("/health", headers=AUTH)
        assert details.json() == {"ok": True, "devices_lost": [], "problems": [], "store": {"journal_mode": "wal"}}
        metrics = await client.get("/metrics", headers=AUTH)
        assert metrics.status_code == 200 and "cellctl_packml_state" in metrics.text
        assert metrics.headers["content-type"].startswith("text/plain")


async def test_health_never_shows_where_the_database_is(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        r = await client.get("/health")  # open reads: the details, anonymously
        assert r.json()["store"] == {"journal_mode": "wal"}
        assert str(tmp_path) not in r.text and ".db" not in r.text


async def test_a_body_over_the_limit_is_refused_before_it_is_read(tmp_path: Path) -> None:
    config = sim_config(plc={"enabled": False}, api={"max_body_bytes": 1024})
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        # Declared too large (a 100 MiB upload): 413 before a byte of it is read, with or without a token.
        for headers in (CYCLE_HEADERS, {"Content-Type": "application/json"}):
            body = CountedBody(chunks=100, size=1024 * 1024)
            r = await client.post("/cycle", content=body, headers={**headers, "Content-Length": str(100 * 1024 * 1024)})
            assert r.status_code == 413 and "max_body_bytes" in r.json()["detail"] and "1024" in r.json()["detail"]
            assert body.pulled == 0
        # Streamed without a length: counted, refused at the chunk that passes the limit.
        body = CountedBody(chunks=100, size=400)
        r = await client.post("/cycle", content=body, headers=CYCLE_HEADERS)
        assert r.status_code == 413 and "max_body_bytes" in r.json()["detail"]
        assert body.pulled == 3
        # Within the limit the request goes on as before (the cell starts Aborted: the cycle is refused).
        r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "P"}, headers=CYCLE_HEADERS)
        assert r.status_code == 409
        assert (await client.get("/cycles")).json() == []


async def test_a_mutating_route_checks_the_token_before_it_reads_the_body(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        for headers in ({}, {"Authorization": "Bearer not-the-token-at-all"}):
            for path in ("/cycle", "/jobs", "/jobs/1/prompts/1"):
                body = CountedBody(chunks=2, size=100)
                r = await client.post(path, content=body, headers={**headers, "Content-Type": "application/json"})
                assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer", (path, r.text)
                assert body.pulled == 0, path
        # A read with a body (planning a job) stays open with open reads: its body is read and judged.
        r = await client.post("/jobs/plan", json={"procedure": "no-such-procedure"})
        assert r.status_code == 422 and "no-such-procedure" in r.json()["detail"]


async def test_a_token_from_a_file_opens_the_mutating_routes(tmp_path: Path) -> None:
    token_file = tmp_path / "integrator.token"
    token_file.write_text("Vq3-xK9_pL2mZ8rT5wY1nB7cD4fG6hJ0\n")
    token_file.chmod(0o600)
    config = sim_config(plc={"enabled": False}, api={"tokens": [{"name": "integrator", "token_file": str(token_file)}]})
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        assert (await client.post("/alarms/acknowledge-all", headers=AUTH)).status_code == 401  # the sim default: not configured
        r = await client.post("/alarms/acknowledge-all", headers={"Authorization": "Bearer Vq3-xK9_pL2mZ8rT5wY1nB7cD4fG6hJ0"})
        assert r.status_code == 200, r.text
        audit = await service.store.audit_entries(limit=1000)
        assert [a.actor for a in audit if a.action == "alarm.acknowledge_all"] == ["integrator"]
