"""The page reads everything again after its event stream reconnects, not only after its data turned stale.

The stream's events sent while it was down are gone (nothing replays them). A drop shorter than the page's
stale limit used to lose them for good: an alarm raised meanwhile never showed, a cycle that ended meanwhile
never reached the filmstrip, and a service restarted with an edited config kept the page on the old settings.
To make "shorter than the stale limit" hold whatever the machine's load, each page here is given a stale limit
of 10 minutes before the drop (the settings read after the reconnect bring the cell's own back). The peer is
the REST API read with httpx; the page is a real headless Chromium.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from dashboard_test_support import AUTH, LiveCell, browser_marks, settle, sim_config, to_execute
from shared_support import free_port

from cellctl.domain import AlarmCode
from cellctl.store import CycleRequest

pytestmark = browser_marks(240)

from playwright.sync_api import expect  # noqa: E402

WAIT_MS = 20_000


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveCell]:
    with LiveCell(tmp_path_factory.mktemp("reconnect"), sim_config()) as live:
        yield live


def _open(pg: Any, url: str) -> None:
    """Load the page, wait for live data, then make its stale limit long: a drop can never reach it."""
    pg.goto(url + "/")
    expect(pg.locator("body")).to_have_attribute("data-ready", "1")
    expect(pg.locator("#live")).to_have_text("live")
    pg.evaluate(
        "() => { const m = window.cellctlDashboard.model; m.config = { ...m.config, stale_after_s: 600 };"
        " window.__wasStale = false; setInterval(() => { if (m.stale) window.__wasStale = true; }, 50); }"
    )


def _back_live(pg: Any) -> None:
    """The page got an event after the drop, and its data never turned stale (the case here)."""
    pg.evaluate("() => { window.__since = Date.now(); }")
    pg.wait_for_function("() => window.cellctlDashboard.model.lastMessageAt > window.__since", timeout=WAIT_MS)
    assert pg.evaluate("() => window.__wasStale") is False, "the page marked its data stale: not a short drop"


def test_an_alarm_raised_while_the_stream_was_down_is_shown(cell: LiveCell, client: httpx.Client, page: Any) -> None:
    pg, log = page
    to_execute(client)
    _open(pg, cell.url)
    expect(pg.locator("#alarm-banner")).to_be_hidden()
    cell.stop_http()
    cell.run(cell.orch.alarms.raise_alarm(AlarmCode.CORNER_NOT_FOUND, source="vision", detail="raised while the network was down"))
    cell.start_http()
    _back_live(pg)
    assert settle(client) == "HELD"
    current = client.get("/alarms").json()["current"]
    assert [a["code"] for a in current] == [int(AlarmCode.CORNER_NOT_FOUND)], current
    expect(pg.locator("#state")).to_have_text("HELD", timeout=WAIT_MS)
    expect(pg.locator("#alarm-banner")).to_be_visible(timeout=WAIT_MS)
    expect(pg.locator(f"#alarms-now [data-alarm='{current[0]['uid']}']")).to_have_count(1, timeout=WAIT_MS)
    assert log.loads == 1  # no reload did it


def test_a_cycle_run_while_the_stream_was_down_reaches_the_filmstrip(cell: LiveCell, client: httpx.Client, page: Any) -> None:
    pg, log = page
    client.post("/alarms/acknowledge-all", headers=AUTH).raise_for_status()
    to_execute(client)
    _open(pg, cell.url)
    cell.stop_http()
    request = CycleRequest(recipe="side-window", part_id="P-DROP-1")
    submitted = cell.run(cell.orch.submit_cycle(request, scope="rest", key="reconnect-drop-1", actor="test"))
    cid = submitted.cycle.id
    cell.run(cell.orch.wait_cycle(cid, 60.0), timeout_s=90.0)
    cell.start_http()
    _back_live(pg)
    rec = client.get(f"/cycles/{cid}").json()
    assert rec["state"] in ("done", "failed"), rec
    expect(pg.locator(f"#filmstrip [data-cycle='{cid}']")).to_contain_text(rec["state"], timeout=WAIT_MS)
    assert log.loads == 1


def _served(workdir: Path, port: int, **sections: Any) -> LiveCell:
    """The cell served on ``port``: a restarted service comes back on the same one."""
    live = LiveCell(workdir, sim_config(**sections))
    live.port = port
    live.start()
    return live


def test_the_settings_of_a_restarted_service_reach_the_page(tmp_path: Path, page: Any) -> None:
    """Restarted with an edited config (the unit mode may now change in Aborted): the page offers it, no reload."""
    pg, log = page
    port = free_port()
    live = _served(tmp_path, port, packml={"mode_change_states": ["stopped", "idle"]})
    try:
        _open(pg, live.url)
        expect(pg.locator("#state")).to_have_text("ABORTED")
        expect(pg.locator("#mode-apply")).to_be_disabled()  # not a mode-change state in this config
    finally:
        live.stop()
    live = _served(tmp_path, port)  # the default config: stopped, idle and aborted
    try:
        with httpx.Client(base_url=live.url, timeout=15.0) as client:
            assert "ABORTED" in client.get("/dashboard/config").json()["mode_change_states"]
            assert settle(client) == "ABORTED"
            _back_live(pg)
            expect(pg.locator("#state")).to_have_text("ABORTED", timeout=WAIT_MS)
            expect(pg.locator("#mode-apply")).to_be_enabled(timeout=WAIT_MS)
            assert log.loads == 1
    finally:
        live.stop()
