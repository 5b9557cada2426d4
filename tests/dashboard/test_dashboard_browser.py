"""The operator dashboard in a real headless Chromium (Debian's, driven by Playwright) against the
real simulated cell service: offline loading, live cycles, alarm acknowledge, command gating,
the stale-data mark. Screenshots go to test-artifacts/dashboard/."""

from __future__ import annotations

import asyncio
import itertools
import re
from collections.abc import Iterator
from typing import Any
from urllib.parse import urlsplit

import httpx
import pytest
from dashboard_test_support import (
    AUTH,
    TOKEN,
    LiveCell,
    PageLog,
    chromium_missing_reason,
    sim_config,
    settle,
    shot,
    to_aborted,
    to_execute,
    wait_cycle,
)

_missing = chromium_missing_reason()
pytestmark = [
    pytest.mark.skipif(_missing is not None, reason=_missing or ""),
    pytest.mark.timeout(120),
]
if _missing is None:
    from playwright.sync_api import Page, expect

_keys = itertools.count(1)


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveCell]:
    with LiveCell(tmp_path_factory.mktemp("dashboard-cell")) as live:
        yield live


def _open(pg: Page, cell: LiveCell, path: str = "/") -> None:
    pg.goto(cell.url + path)
    expect(pg.locator("body")).to_have_attribute("data-ready", "1")


def _submit(client: httpx.Client, part_id: str, car_id: str | None = None) -> int:
    body: dict[str, Any] = {"recipe": "side-window", "part_id": part_id}
    if car_id is not None:
        body["car_id"] = car_id
    r = client.post("/cycle", json=body, headers={**AUTH, "Idempotency-Key": f"dash-{next(_keys)}-{part_id}"})
    assert r.status_code == 202, r.text
    return int(r.json()["cycle_id"])


_SET_CALIBRATION = {
    "current": {
        "source": "/var/lib/cellctl/calibration",
        "version": 4,
        "parts": {
            "camera": {"status": "ok", "calibrated_utc": "2026-01-05T08:00:00+00:00", "method": "zhang",
                       "quality": {"rms_px": 0.21, "views": 24}, "failure": None},
            "hand_eye": {"status": "failed", "calibrated_utc": "2026-01-05T09:00:00+00:00", "method": "park-martin",
                         "quality": {}, "failure": "rotation spread 3 deg is below 30 deg"},
            "teaching": None,
        },
        "recipes": {"side-window": {"taught": True, "ready": False}, "door-window": {"taught": False, "ready": False}},
    },
    "problems": ["hand_eye: failed (rotation spread 3 deg is below 30 deg): run `cellctl calibrate hand-eye`"],
    "versions": [  # oldest first, as GET /calibration lists them
        {"version": 3, "created_utc": "2026-01-05T08:00:00+00:00", "note": "camera: job 1",
         "parts": {"camera": "ok", "hand_eye": None, "teaching": None}},
        {"version": 4, "created_utc": "2026-01-05T09:00:00+00:00", "note": "hand_eye: job 2",
         "parts": {"camera": "ok", "hand_eye": "failed", "teaching": None}},
    ],
}  # fmt: skip


def _signed(v: float, digits: int = 3) -> str:
    return f"{v:+.{digits}f}"


def test_dashboard_loads_offline_with_forbidden_commands_disabled(
    cell: LiveCell, client: httpx.Client, page: tuple[Page, PageLog]
) -> None:
    pg, log = page
    to_aborted(client)
    _open(pg, cell)
    expect(pg.locator("#state")).to_have_text("ABORTED")
    expect(pg.locator("#tile-state")).to_have_class("tile tile-state is-alarm")
    # The state table allows only Clear in Aborted: every other command is greyed out.
    expect(pg.locator("[data-command=clear]")).to_be_enabled()
    for cmd in ("reset", "start", "stop", "hold", "unhold", "suspend", "unsuspend", "complete", "abort"):
        expect(pg.locator(f"[data-command={cmd}]")).to_be_disabled()
    expect(pg.locator("[data-command=start]")).to_have_attribute("title", re.compile("not allowed in ABORTED"))
    # Aborted is a mode-change state in the configuration: the mode control is open.
    expect(pg.locator("#mode-apply")).to_be_enabled()
    # Every device of the simulated cell shows its link and heartbeat age.
    for dev in ("laser", "camera", "robot"):
        expect(pg.locator(f"#devices [data-device={dev}]")).to_contain_text("up")
    expect(pg.locator("#cal")).to_have_text("ready")
    expect(pg.locator("#live")).to_have_text("live")
    # The style sheet came from the package: the calm grey background is applied.
    assert pg.evaluate("getComputedStyle(document.body).backgroundColor") == "rgb(212, 212, 212)"
    shot(pg, "01-aborted-offline.png")
    # The unit mode changes from the page (with the operator token) and back.
    pg.fill("#token", TOKEN)
    pg.click("#token-save")
    for mode in ("maintenance", "production"):
        pg.select_option("#mode-select", mode)
        pg.click("#mode-apply")
        expect(pg.locator("#mode")).to_have_text(mode.upper())
        assert client.get("/status").json()["mode"] == mode.upper()
    # The calibration page renders the current set; keyboard focus reaches the pages' links.
    pg.focus("nav a[data-page=calibration]")
    pg.keyboard.press("Enter")
    expect(pg.locator("#page-calibration")).to_be_visible()
    expect(pg.locator("#cal-problems")).to_contain_text("Ready for production")
    expect(pg.locator("#cal-current")).to_contain_text("source")
    expect(pg.locator("#cal-recipes [data-recipe=side-window]")).to_contain_text("ready")
    shot(pg, "07-calibration.png")
    # A versioned calibration set (as calibration.source = "set" reports it) shows one row per part,
    # a failed part in alarm colour and a missing one in warning colour.
    pg.route("**/calibration", lambda route: route.fulfill(json=_SET_CALIBRATION))
    pg.click("nav a[data-page=overview]")
    pg.click("nav a[data-page=calibration]")
    expect(pg.locator("#cal-problems")).to_contain_text("hand_eye: failed")
    expect(pg.locator("#cal-parts [data-part=camera]")).to_contain_text("rms_px")
    expect(pg.locator("#cal-parts [data-part=hand_eye] td").first).to_have_class("is-alarm")
    expect(pg.locator("#cal-parts [data-part=teaching] td").first).to_have_class("is-warn")
    # each recipe: its own teaching, and whether its cycles may run
    expect(pg.locator("#cal-recipes [data-recipe=side-window]")).to_contain_text("taught")
    expect(pg.locator("#cal-recipes [data-recipe=door-window] td").first).to_have_text("not taught")
    expect(pg.locator("#cal-recipes [data-recipe=door-window] td").first).to_have_class("is-warn")
    # The set's versions, newest first; the one in use is marked, its failed part in alarm colour.
    versions = pg.locator("#cal-history tbody tr")
    expect(versions).to_have_count(2)
    expect(versions.first).to_have_attribute("data-version", "4")
    expect(versions.first).to_contain_text("(in use)")
    expect(versions.first.locator("td[data-part=hand_eye]")).to_have_class("is-alarm")
    expect(versions.nth(1)).to_contain_text("camera: job 1")
    pg.unroute("**/calibration")
    assert any(u.endswith("/ui/app.js") for u in log.requests)
    assert any(u.endswith("/ui/style.css") for u in log.requests)
    assert any(urlsplit(u).path == "/events" for u in log.requests)
    assert log.foreign() == [], log.foreign()
    assert log.errors == [], log.errors


def test_dashboard_shows_a_cycle_started_through_the_api_live(
    cell: LiveCell, client: httpx.Client, page: tuple[Page, PageLog]
) -> None:
    pg, log = page
    to_execute(client)
    _open(pg, cell)
    expect(pg.locator("#state")).to_have_text("EXECUTE")
    loaded_at = pg.evaluate("window.cellctlDashboard.loadedAt")
    cid = _submit(client, "P-LIVE-1", "CAR-7")
    rec = wait_cycle(client, cid)
    assert rec["state"] == "done", rec
    # Without a reload: the filmstrip, the last image, the header and the trends follow the cycle.
    expect(pg.locator(f"#filmstrip [data-cycle='{cid}']")).to_contain_text("P-LIVE-1")
    expect(pg.locator("#last-image")).to_have_attribute("data-cycle", str(cid))
    expect(pg.locator("#part")).to_have_text("last: P-LIVE-1 / CAR-7")
    # The trends show what the cell measured after the install (the truth is in the cycle's detail).
    md = rec["measured_deviation"]
    expect(pg.locator("#h-trends")).to_have_text("Install deviation: measured after the install")
    for key, axis in (("dx_mm", "dx_mm"), ("dy_mm", "dy_mm"), ("dz_mm", "dz_mm"), ("drx_deg", "drx_deg")):
        expect(pg.locator(f"#trend-charts [data-axis={axis}] .chart-value")).to_have_text(_signed(md[key]))
    # The closed loops' panel, one loop per recipe: the side window's one result counted, no offset yet
    # (it needs min_samples); the door window's loop has none.
    expect(pg.locator("#spc")).to_contain_text("side-window: loop on; 1 result counted")
    expect(pg.locator("#spc")).to_contain_text("door-window: loop on; 0 results counted")
    expect(pg.locator("#spc [data-spc=table][data-recipe=side-window] tbody tr")).to_have_count(2)
    expect(pg.locator("#cycle-time-chart .chart-value")).to_have_text(f"{rec['result']['cycle_time_s']:.2f}")
    # The simulated cell lands within the paper's tolerance: nothing outside the bands, no colour.
    for axis in ("dx_mm", "dy_mm", "dz_mm", "drx_deg", "dry_deg", "drz_deg"):
        expect(pg.locator(f"#trend-charts [data-axis={axis}]")).to_have_attribute("data-outside", "0")
    assert pg.evaluate("window.cellctlDashboard.loadedAt") == loaded_at
    assert log.loads == 1
    shot(pg, "02-cycle-live.png")
    # The filmstrip opens the cycle's detail: its steps, figures and images.
    expect(pg.locator(f"#filmstrip [data-cycle='{cid}']")).to_contain_text("done")
    pg.click(f"#filmstrip [data-cycle='{cid}']")
    detail = pg.locator("#cycle-detail")
    expect(detail.locator("h2")).to_have_text(f"Cycle {cid}: done")
    expect(detail.locator("table.steps")).to_contain_text("compensate")
    expect(detail.locator("table.steps")).to_contain_text("fit_rms_mm")
    expect(detail).to_contain_text("Measured after the install")
    expect(detail).to_contain_text("True (simulation)")
    expect(detail.locator("table.steps")).to_contain_text("inspect")
    thumb = detail.locator(".thumbs img").first
    thumb.scroll_into_view_if_needed()
    pg.wait_for_function("img => img.complete && img.naturalWidth === 320", arg=thumb.element_handle())
    # History filters: by part id (in the page) and by state (from the API).
    other = _submit(client, "Q-OTHER-2")
    wait_cycle(client, other)
    expect(pg.locator(f"#cycle-table tbody tr[data-cycle='{other}']")).to_be_visible()
    pg.fill("#filter-part", "p-live")
    expect(pg.locator("#cycle-table tbody tr")).to_have_count(1)
    expect(pg.locator("#cycle-table tbody tr").first).to_have_attribute("data-cycle", str(cid))
    pg.fill("#filter-part", "")
    pg.select_option("#filter-state", "failed")
    expect(pg.locator(f"#cycle-table tbody tr[data-cycle='{cid}']")).to_have_count(0)
    pg.select_option("#filter-state", "done")
    expect(pg.locator(f"#cycle-table tbody tr[data-cycle='{cid}']")).to_have_count(1)
    shot(pg, "03-cycle-detail.png")
    assert log.loads == 1
    assert log.foreign() == [], log.foreign()
    assert log.errors == [], log.errors


@pytest.fixture(scope="module")
def strict_cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveCell]:
    """A cell whose correction limit (0.5 mm) is far below the car bodies' spread (+-20 mm): the
    alignment's correction is refused, the cycle fails and the cell holds for the operator."""
    config = sim_config(**{"process.limits": {"max_correction_mm": 0.5}})
    with LiveCell(tmp_path_factory.mktemp("dashboard-strict"), config) as live:
        yield live


@pytest.fixture(scope="module")
def strict_client(strict_cell: LiveCell) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=strict_cell.url, timeout=15.0) as c:
        yield c


def test_dashboard_acknowledges_an_alarm_and_gates_unhold(
    strict_cell: LiveCell, strict_client: httpx.Client, page: tuple[Page, PageLog]
) -> None:
    pg, log = page
    cell, client = strict_cell, strict_client
    to_execute(client)
    _open(pg, cell)
    pg.evaluate("sessionStorage.clear()")
    cid = _submit(client, "P-NOK-3")
    rec = wait_cycle(client, cid)
    assert rec["state"] == "failed", rec
    assert "limit" in rec["error"], rec["error"]
    assert settle(client) == "HELD"
    current = client.get("/alarms").json()["current"]
    assert [a["code"] for a in current] == [1304], current
    uid = current[0]["uid"]
    # The banner names the first-out reason; the alarm waits for acknowledgement.
    banner = pg.locator("#alarm-banner")
    expect(banner).to_be_visible()
    expect(pg.locator("#first-out")).to_contain_text("First-out: 1304")
    expect(pg.locator("#state")).to_have_text("HELD")
    # Unhold exists in Held but the alarm holds it back: disabled, and the reason is shown.
    unhold = pg.locator("[data-command=unhold]")
    expect(unhold).to_be_disabled()
    expect(unhold).to_have_attribute("title", re.compile("acknowledge it first"))
    expect(pg.locator("#blocked")).to_contain_text("acknowledge it first")
    expect(pg.locator("[data-command=start]")).to_be_disabled()
    # The refused cycle is pinned at the front of the filmstrip.
    pinned = pg.locator("#filmstrip .film.is-pinned").first
    expect(pinned).to_have_attribute("data-cycle", str(cid))
    shot(pg, "04-alarm-held.png")
    # Without a token the page asks for one and nothing is acknowledged.
    ack = pg.locator(f"#alarms-now [data-alarm='{uid}'] [data-ack]")
    ack.click()
    expect(pg.locator("#message")).to_contain_text("enter the operator token")
    assert client.get("/alarms").json()["current"][0]["acknowledged"] is False
    # With the token (typed into the page, kept in sessionStorage) the acknowledge goes through.
    pg.fill("#token", TOKEN)
    pg.click("#token-save")
    assert pg.evaluate("sessionStorage.getItem('cellctl.operatorToken')") == TOKEN
    expect(pg.locator("#token")).to_have_value("")
    ack.click()
    expect(pg.locator("#message")).to_contain_text("acknowledged by operator")
    expect(pg.locator(f"#alarms-now [data-alarm='{uid}']")).to_have_count(0)
    expect(unhold).to_be_enabled()
    alarms = client.get("/alarms", params={"history": "true"}).json()
    acked = next(a for a in alarms["history"] if a["uid"] == uid)
    assert acked["acknowledged"] and acked["ack_by"] == "operator"
    shot(pg, "05-alarm-acknowledged.png")
    pg.click("nav a[data-page=alarms]")
    expect(pg.locator(f"#alarms-history [data-alarm='{uid}']")).to_contain_text("ack by operator")
    pg.fill("#alarm-filter", "no such alarm text")
    expect(pg.locator(f"#alarms-history [data-alarm='{uid}']")).to_have_count(0)
    pg.fill("#alarm-filter", "1304")
    expect(pg.locator(f"#alarms-history [data-alarm='{uid}']")).to_have_count(1)
    shot(pg, "08-alarm-history.png")
    pg.click("nav a[data-page=overview]")
    # The page's own command button brings the cell back to production.
    unhold.click()
    expect(pg.locator("#state")).to_have_text("EXECUTE")
    assert settle(client) == "EXECUTE"
    assert log.foreign() == [], log.foreign()
    assert log.errors == [], log.errors


def test_dashboard_marks_stale_data_and_recovers(cell: LiveCell, page: tuple[Page, PageLog]) -> None:
    pg, log = page
    _open(pg, cell)
    expect(pg.locator("#live")).to_have_text("live")
    cell.stop_http()
    try:
        expect(pg.locator("#live")).to_contain_text("STALE", timeout=12_000)
        expect(pg.locator("#tile-live")).to_have_class("tile tile-live is-warn")
        expect(pg.locator("body")).to_have_class(re.compile(r"\bstale\b"))
        shot(pg, "06-stale.png")
    finally:
        cell.start_http()
    # The browser reconnects by itself and the mark goes away.
    expect(pg.locator("#live")).to_have_text("live", timeout=20_000)
    expect(pg.locator("body")).not_to_have_class(re.compile(r"\bstale\b"))
    assert log.foreign() == [], log.foreign()


def test_a_page_opened_after_the_plc_came_up_shows_its_link(tmp_path_factory: pytest.TempPathFactory, page: tuple[Page, PageLog]) -> None:
    from plc_test_support import PlcClient
    from pymodbus.client import AsyncModbusTcpClient

    pg, log = page
    config = sim_config(plc={"enabled": True, "port": 0, "scan_period_s": 0.01, "heartbeat_alarm": False, "heartbeat_timeout_s": 30.0})
    with LiveCell(tmp_path_factory.mktemp("dashboard-plc"), config) as live:
        assert live.orch.status()["links"]["plc"]["link"] == "waiting"
        port = live.service.plc_server.port  # type: ignore[union-attr]

        async def beat_until_up() -> None:
            client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=1)
            assert await client.connect()
            plc = PlcClient(client, config.plc.float_word_order, unit_id=config.plc.unit_id)
            try:
                for n in range(1, 100):
                    await plc.write(plc_heartbeat=n)
                    if live.orch.status()["links"]["plc"]["link"] == "up":
                        return
                    await asyncio.sleep(0.02)
                raise AssertionError("the PLC link never came up")
            finally:
                client.close()

        live.run(beat_until_up())
        # The page opens after the change: it learns the link from /status, not from an event.
        _open(pg, live)
        expect(pg.locator('#devices li[data-device="plc"]')).to_contain_text("up since")
        assert log.errors == [], log.errors
