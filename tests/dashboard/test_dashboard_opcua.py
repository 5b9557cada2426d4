"""A cycle the plant starts over OPC UA (an independent asyncua client, encrypted) appears on the operator's
dashboard in a real Chromium, live, with its part, car body and result."""

from __future__ import annotations

import asyncio
import concurrent.futures
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from dashboard_test_support import (
    LiveCell,
    PageLog,
    chromium_missing_reason,
    sim_config,
    to_execute,
    wait_cycle,
)
from opcua_test_support import call, ns_of, opcua_client

_missing = chromium_missing_reason()
pytestmark = [pytest.mark.skipif(_missing is not None, reason=_missing or ""), pytest.mark.timeout(120)]
if _missing is None:
    from playwright.sync_api import expect

PASSWORD = "dashboard-opcua-password-0123"


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveCell]:
    config = sim_config(opcua={"enabled": True, "port": 0, "allow_anonymous": False,
                               "security_policies": ["Basic256Sha256_SignAndEncrypt"],
                               "users": [{"name": "mes", "password": PASSWORD}]})  # fmt: skip
    with LiveCell(tmp_path_factory.mktemp("dashboard-opcua"), config) as live:
        yield live


def _start_over_opcua(cell: LiveCell, folder: Path, part: str, car: str, request_id: str) -> int:
    async def run() -> int:
        async with opcua_client(cell.service, folder, user="mes", password=PASSWORD) as client:  # type: ignore[arg-type]
            return int(await call(client, await ns_of(client), "Cycle.StartCycle", "side-window", part, car, request_id))

    with concurrent.futures.ThreadPoolExecutor(1) as pool:  # Playwright's sync API owns this thread's loop
        return pool.submit(asyncio.run, run()).result(60)


def test_a_cycle_started_over_opcua_shows_on_the_dashboard(
    cell: LiveCell, client: httpx.Client, page: tuple[Any, PageLog], tmp_path: Path
) -> None:
    pg, log = page
    to_execute(client)
    pg.goto(cell.url + "/")
    expect(pg.locator("body")).to_have_attribute("data-ready", "1")
    cid = _start_over_opcua(cell, tmp_path, "P-OPCUA-1", "CAR-UA", "mes-req-1")
    rec = wait_cycle(client, cid)
    assert rec["state"] == "done" and rec["source"] == "opcua", rec
    film = pg.locator(f"#filmstrip [data-cycle='{cid}']")
    expect(film).to_contain_text("P-OPCUA-1")
    expect(film).to_contain_text("done")  # its last render: a click is not raced by the strip's rebuild
    expect(pg.locator("#part")).to_have_text("last: P-OPCUA-1 / CAR-UA")
    pg.click(f"#filmstrip [data-cycle='{cid}']")
    expect(pg.locator("#cycle-detail h2")).to_have_text(f"Cycle {cid}: done")
    assert log.errors == [], log.errors
