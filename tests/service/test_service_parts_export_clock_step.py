"""The MES export across wall-clock steps and a restart: every ended install is exported exactly once.

docs/traceability.md: an MES that exports periodically passes the previous run's applied bound as the next
``--since`` and gets every ended install once. Here the cell PC's wall clock is stepped as NTP steps it (back 30 s,
back 1 h, or ahead 1 h and then back), in this process (the service) and in the ``cellctl parts export`` subprocess
(the same host): every cellctl module's ``datetime.now()`` and ``time.time()`` are shifted, ``time.monotonic()`` is
not. The export runs as the real ``cellctl`` against the service on a loopback port, and also as ``GET /parts`` over
httpx. Truth is the ``cycles`` table read by an independent sqlite3 connection on the store file.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import sqlite3
import sys
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_test_support import AUTH, TOKEN, api_client, running_service, served, sim_config, to_execute

import clock_step_support as clock_steps

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def wall() -> Iterator[Any]:
    """The wall clock this process's cellctl modules read (clock_step_support), stepped by ``wall.step(seconds)``."""
    clock_steps.install()
    try:
        yield clock_steps
    finally:
        clock_steps.uninstall()


async def install(client: httpx.AsyncClient, key: str) -> int:
    r = await client.post("/cycle?wait=true&timeout_s=60", json={"recipe": "side-window", "part_id": key, "car_id": "CAR-1"},
                          headers={**AUTH, "Idempotency-Key": key})  # fmt: skip
    assert r.status_code == 200 and r.json()["state"] == "done", r.text
    return int(r.json()["id"])


async def cli_parts_export(url: str, wall: Any, *args: str) -> tuple[int, str]:
    """``cellctl parts export --url URL ARGS`` on this host's stepped clock: its exit status and standard error."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, clock_steps.__file__, "--config", str(ROOT / "config" / "sim.toml"), "parts", "export", "--url", url,
        *args, stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        env={**os.environ, "CELLCTL_TOKEN": TOKEN, clock_steps.OFFSET_ENV: str(wall.OFFSET[0].total_seconds())},
    )  # fmt: skip
    _, err = await asyncio.wait_for(proc.communicate(), 60)
    return int(proc.returncode or 0), err.decode()


async def cli_export(url: str, wall: Any, since: str, out: Path, faults: list[str]) -> tuple[list[int], str]:
    """``cellctl parts export --since SINCE`` (no --until) on this host's stepped clock: the ids and the bound applied.
    A refusal is noted in ``faults``, and the MES tries the same ``since`` at its next period."""
    code, err = await cli_parts_export(url, wall, "--since", since, "--output", str(out))
    found = re.search(r"\(ended (\S+) to (\S+)\)", err)
    if code != 0 or not found or found[1] != since:
        faults.append(f"cellctl parts export --since {since}: exit {code}: {err.strip()}")
        return [], since
    return [json.loads(line)["cycle_id"] for line in out.read_text(encoding="utf-8").splitlines()], found[2]


async def api_export(client: httpx.AsyncClient, since: str, faults: list[str]) -> tuple[list[int], str]:
    """Every page of ``GET /parts?since=SINCE&until=<far ahead>``, the bound the first page applied kept for the rest;
    a window answered inverted, or an install whose ``ended_at`` lies outside it, is noted in ``faults``."""
    ids: list[int] = []
    params: dict[str, Any] = {"since": since, "until": "2999-01-01T00:00:00+00:00", "limit": 1}
    while True:
        r = await client.get("/parts", params=params)
        assert r.status_code == 200, r.text
        page = r.json()
        ids += [i["cycle_id"] for i in page["installs"]]
        start, end = datetime.fromisoformat(since), datetime.fromisoformat(page["until"])
        if end < start:
            faults.append(f"GET /parts?since={since} answered until {page['until']}, earlier")
        for i in page["installs"]:  # the window is on the end stamp the document shows
            if not (i.get("ended_at") and start <= datetime.fromisoformat(i["ended_at"]) < end):
                faults.append(f"cycle {i['cycle_id']} ended_at {i.get('ended_at')} is outside [{since}, {page['until']})")
        params["until"] = page["until"]
        if page["next"] is None:
            return ids, page["until"]
        params["after"] = page["next"]


def ended_in_store(workdir: Path) -> list[int]:
    """The ids of the ended cycles, read by sqlite3 on the store file."""
    (path,) = workdir.rglob("cellctl.db")
    with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as conn:
        rows = conn.execute("SELECT id FROM cycles WHERE state IN ('done', 'failed', 'interrupted') ORDER BY id")
        return [int(r[0]) for r in rows]


@pytest.mark.parametrize("step_s", [-30.0, -3600.0, 3600.0])
async def test_periodic_exports_list_every_install_once_across_clock_steps_and_a_restart(
    tmp_path: Path, wall: Any, step_s: float
) -> None:
    cfg = sim_config(plc={"enabled": False}, opcua={"enabled": False})
    exported: list[int] = []
    faults: list[str] = []
    since = (datetime.now(timezone.utc) - timedelta(days=1)).isoformat()  # the MES's first run
    files = iter(tmp_path / f"export-{n}.jsonl" for n in range(100))

    async def export_both_ways(client: httpx.AsyncClient, url: str) -> None:
        nonlocal since
        ids, since = await cli_export(url, wall, since, next(files), faults)
        exported.extend(ids)
        ids, since = await api_export(client, since, faults)  # an MES on the API, right after, continues the chain
        exported.extend(ids)

    async with running_service(tmp_path, cfg) as service, api_client(service) as client, served(service) as url:
        await to_execute(client)
        await install(client, "G-1")
        await export_both_ways(client, url)
        wall.step(step_s)  # NTP steps the clock (ahead: a clock that was set wrong)
        await install(client, "G-2")  # ends in the second the step took back (or far ahead)
        await export_both_ways(client, url)
        await install(client, "G-3")
        wall.step(-step_s)  # back to the time before (the clock caught up, or NTP corrected the one ahead)
        await install(client, "G-4")
        await export_both_ways(client, url)
    wall.step(-120.0)  # the service restarts on a clock 2 min behind
    async with running_service(tmp_path, cfg) as service, api_client(service) as client, served(service) as url:
        await to_execute(client)
        await install(client, "G-5")
        await export_both_ways(client, url)
        wall.step(120.0)
        await install(client, "G-6")
        await export_both_ways(client, url)
        code, err = await cli_parts_export(url, wall, "--since", since, "--until", since)  # an explicit empty window
        assert code == 2 and "--until" in err and "must be later than --since" in err and len(err.strip().splitlines()) == 1, err

    truth = ended_in_store(tmp_path)
    assert len(truth) == 6
    assert sorted(exported) == truth, f"never exported: {sorted(set(truth) - set(exported))}; exported: {exported}"
    assert faults == []
