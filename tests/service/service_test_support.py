"""A whole simulated cell service for tests: the real composition, a temporary workdir, port 0."""

from __future__ import annotations

import contextlib
import tomllib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import httpx

from cellctl.config import CellConfig, parse_config
from cellctl.service import build_service
from cellctl.service.compose import Service

ROOT = Path(__file__).resolve().parents[2]
TOKEN = "sim-operator-token-change-me"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def sim_config(**sections: dict[str, Any]) -> CellConfig:
    """config/sim.toml with some sections' fields replaced.

    Unless a test says otherwise the calibration is the twin's truth (the oracle): self-calibrating
    from simulated data takes half a minute, which the calibration tests cover on their own.
    """
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    sections.setdefault("calibration", {"source": "oracle"})
    for name, fields in sections.items():
        node = data
        for part in name.split("."):
            node = node.setdefault(part, {})
        node.update(fields)
    return parse_config(data, "sim.toml (test)")


@contextlib.asynccontextmanager
async def running_service(workdir: Path, config: CellConfig | None = None) -> AsyncIterator[Service]:
    cfg = config or sim_config(plc={"port": 0, "scan_period_s": 0.005})
    service = await build_service(cfg, workdir=workdir)
    await service.start()
    try:
        yield service
    finally:
        await service.stop()


@contextlib.asynccontextmanager
async def api_client(service: Service) -> AsyncIterator[httpx.AsyncClient]:
    from cellctl.api.app import create_app

    app = create_app(service.orchestrator, service.config.api, service.jobs)
    async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://cell") as client:
        yield client


async def to_execute(client: httpx.AsyncClient) -> None:
    """Clear, reset and start the cell over REST, waiting out the acting states."""
    import asyncio

    for cmd in ("clear", "reset", "start"):
        r = await client.post(f"/commands/{cmd}", headers=AUTH)
        assert r.status_code == 200, r.text
        for _ in range(200):
            state = (await client.get("/status")).json()["state"]
            if not state.endswith("ING"):
                break
            await asyncio.sleep(0.01)
    assert state == "EXECUTE", state
