"""The dashboard at the operator's two screens, 1920x1080 and 1024x768, in a real headless Chromium
against the simulated cell (issue 20): no page wider than the screen, a cycle's detail (with a
calibrate step carrying a whole calibration set's summary) under three screen heights, the
first-out alarm's text and the alarm list without scrolling, the state's own mark, the shift
counters, the calibration's due date, dates in the alarm history, charts whose scale follows the
data, and every control disabled (with the reason shown) while the data is stale. Screenshots go
to test-artifacts/dashboard/ (20-*.png)."""

from __future__ import annotations

import copy
import re
from collections.abc import Iterator
from datetime import datetime, timezone
from typing import Any

import httpx
import pytest
from dashboard_test_support import (
    LiveCell,
    PageLog,
    browser_marks,
    chromium_missing_reason,
    install_cycles,
    shot,
)

from cellctl.api.dashboard import SHIFT_STARTS
from cellctl.domain import AlarmCode

pytestmark = browser_marks()
if not chromium_missing_reason():
    from playwright.sync_api import Page, expect

VIEWPORTS = [(1920, 1080), (1024, 768)]
PAGES = ("overview", "cycles", "alarms", "calibration", "commissioning")


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveCell]:
    with LiveCell(tmp_path_factory.mktemp("dashboard-layout")) as live:
        yield live


@pytest.fixture(scope="module")
def cycle_ids(cell: LiveCell, client: httpx.Client) -> list[int]:
    """Three installed cycles, then a fault that stops the cell: the first-out alarm."""
    ids = [int(r["id"]) for r in install_cycles(client, "layout", [(f"P-LAYOUT-{n}", None) for n in range(3)])]
    cell.run(cell.orch.alarms.raise_alarm(AlarmCode.ROBOT_FAULT, source="robot", detail="joint 3 over temperature"))
    assert client.get("/alarms").json()["stop_reason"]["code"] == int(AlarmCode.ROBOT_FAULT)
    return ids


def _mid_shift_zone() -> str:
    """A fixed-offset time zone whose local time is 4 h into a shift (starts 06, 14, 22): the module's cycles count
    in the page's current shift whatever the time of day the test runs at."""
    east = (2 - datetime.now(timezone.utc).hour) % 8  # local hour 2, 10 or 18
    return "Etc/GMT" if east == 0 else f"Etc/GMT-{east}"  # the IANA sign is reversed: Etc/GMT-3 is UTC+3


def _sized(browser: Any, width: int, height: int) -> tuple[Any, Page, PageLog]:
    assert SHIFT_STARTS == ("06:00", "14:00", "22:00"), SHIFT_STARTS  # what _mid_shift_zone counts on
    context = browser.new_context(viewport={"width": width, "height": height}, timezone_id=_mid_shift_zone())
    pg = context.new_page()
    log = PageLog()
    pg.on("console", lambda m: log.errors.append(m.text) if m.type == "error" else None)
    pg.on("pageerror", lambda e: log.errors.append(str(e)))
    pg.set_default_timeout(15_000)
    return context, pg, log


def _bulky_calibrate_step(record: dict[str, Any]) -> dict[str, Any]:
    """The record with its calibrate step carrying a whole calibration set's summary (long keys,
    per-view residuals): what made a cycle's page 81,000 px tall."""
    rec = copy.deepcopy(record)
    views = [{"view": f"view_{i:02d}", "rms_px": 0.2 + i / 100, "corners": 88} for i in range(40)]
    summary = {
        "source": "/var/lib/cellctl/calibration/a/rather/long/path/to/the/calibration/set/directory",
        "version": 17,
        "parts": {
            name: {"status": "ok", "calibrated_utc": "2026-01-05T08:00:00+00:00", "method": "zhang",
                   "quality": {"rms_px": 0.21, "per_view_reprojection_error_in_pixels_after_refinement": views,
                               "camera_matrix": [[2400.1, 0, 1024.2], [0, 2400.3, 1011.9], [0, 0, 1]]}}
            for name in ("camera", "hand_eye", "laser_to_flange", "teaching")
        },
    }  # fmt: skip
    for step in rec["steps"]:
        if step["step"] == "calibrate":
            step["figures"] = {"calibration": summary, "install_offset": step["figures"].get("install_offset")}
    return rec


def _fits_width(pg: Page) -> bool:
    return bool(pg.evaluate("document.documentElement.scrollWidth <= window.innerWidth"))


@pytest.mark.parametrize(("width", "height"), VIEWPORTS, ids=lambda v: str(v))
def test_every_page_fits_the_screen_and_the_alarm_reads_without_scrolling(
    cell: LiveCell, client: httpx.Client, cycle_ids: list[int], browser: Any, width: int, height: int
) -> None:
    context, pg, log = _sized(browser, width, height)
    try:
        pg.goto(cell.url + "/")
        expect(pg.locator("body")).to_have_attribute("data-ready", "1")
        # The banner says what stopped the cell, in words, inside the screen without scrolling.
        first_out = pg.locator("#first-out")
        expect(first_out).to_contain_text("First-out: 1401")
        box = pg.evaluate("(() => { const r = document.getElementById('first-out').getBoundingClientRect(); return [r.top, r.bottom, r.left, r.right]; })()")
        assert box[0] >= 0 and box[1] <= height and box[2] >= 0 and box[3] <= width, box
        # The current alarm list is above the fold too.
        row = pg.locator("#alarms-now tbody tr").first
        expect(row).to_contain_text("1401")
        assert row.evaluate("r => r.getBoundingClientRect().bottom") <= height
        # The state reads by its word and a mark of its own shape (the fault aborted the cell).
        expect(pg.locator("#state")).to_have_text("ABORTED")
        expect(pg.locator("#state-mark svg")).to_have_attribute("data-mark", "aborted")
        # Every state the cell rests in has a shape of its own (STOPPED, IDLE and EXECUTE too).
        kinds = pg.evaluate("""async () => { const m = await import('/ui/statemark.js');
            return ['EXECUTE', 'IDLE', 'STOPPED', 'HELD', 'SUSPENDED', 'ABORTED', 'COMPLETE', 'RESETTING'].map(m.stateKind); }""")
        assert len(set(kinds)) == len(kinds), kinds
        # Shift counters: the three good parts of this shift, and the takt.
        current = pg.locator("#shifts tr[data-shift=current]")
        expect(current.locator("[data-count=good]")).to_have_text("3")
        expect(current.locator("[data-count=not-ok]")).to_have_text("0")
        expect(current).to_contain_text(" s")
        # The deviation charts scale to the data and say so; a band beyond the scale is marked.
        dx = pg.locator("#trend-charts [data-axis=dx_mm]")
        expect(dx).to_have_attribute("data-points", "3")
        assert (dx.get_attribute("data-scale") or "").endswith(" mm")
        if dx.get_attribute("data-band") == "off-scale":
            expect(dx.locator(".band-note")).to_contain_text("off scale")
        assert pg.locator("#cycle-time-chart [data-axis=cycle_time_s]").get_attribute("data-scale")
        # Axis labels are screen pixels (not a scaled-down drawing): at least 12 px tall.
        assert pg.locator("#trend-charts .tick").first.evaluate("t => t.getBoundingClientRect().height") >= 12
        assert _fits_width(pg), "overview"
        shot(pg, f"20-{width}x{height}-overview.png")
        # Every page fits the screen's width.
        for name in PAGES[1:]:
            pg.click(f"nav a[data-page={name}]")
            expect(pg.locator(f"#page-{name}")).to_be_visible()
            pg.wait_for_timeout(200)
            assert _fits_width(pg), name
        # The history names the day of each alarm.
        pg.click("nav a[data-page=alarms]")
        expect(pg.locator("#alarms-history td.when").first).to_have_text(re.compile(r"^\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2}$"))
        shot(pg, f"20-{width}x{height}-alarms.png")
        # The calibration's due date: the part that expires first, by each part's own expiry as the service states it.
        # A part's quality is a long record (per-view residuals): folded, the page stays short.
        views = _bulky_calibrate_step({"steps": [{"step": "calibrate", "figures": {}}]})["steps"][0]["figures"]["calibration"]["parts"]["camera"]["quality"]
        pg.route("**/calibration", lambda route: route.fulfill(json={
            "current": {"source": "set", "version": 2, "parts": {
                "camera": {"status": "ok", "calibrated_utc": "2026-01-05T08:00:00+00:00", "expires_utc": "2026-04-05T08:00:00+00:00",
                           "method": "zhang", "quality": views, "failure": None},
                "hand_eye": {"status": "ok", "calibrated_utc": "2026-02-01T08:00:00+00:00", "expires_utc": "2026-05-02T08:00:00+00:00",
                             "method": "park", "quality": views, "failure": None},
            }}, "problems": [], "versions": []}))  # fmt: skip
        pg.click("nav a[data-page=overview]")
        pg.click("nav a[data-page=calibration]")
        expect(pg.locator("#cal-due-line")).to_contain_text("camera expires first")
        expect(pg.locator("#cal-due-line")).to_contain_text(re.compile(r"Due 2026-04-0[45]"))
        expect(pg.locator("#cal-parts td[data-due=hand_eye]")).to_have_text(re.compile(r"2026-05-0[12]"))
        expect(pg.locator("#cal-due")).to_contain_text(re.compile(r"due 2026-04-0[45]"))
        assert _fits_width(pg), "calibration"
        assert pg.evaluate("document.documentElement.scrollHeight") < 3 * height, "calibration"
        shot(pg, f"20-{width}x{height}-calibration.png")
        pg.unroute("**/calibration")
        # A cycle's detail, its calibrate step carrying a whole calibration summary, stays under
        # three screen heights and within the width.
        cid = cycle_ids[0]
        bulky = _bulky_calibrate_step(client.get(f"/cycles/{cid}").json())
        pg.route(f"**/cycles/{cid}", lambda route: route.fulfill(json=bulky))
        pg.goto(f"{cell.url}/#/cycles/{cid}")
        expect(pg.locator("#cycle-detail h2")).to_have_text(f"Cycle {cid}: done")
        expect(pg.locator("#cycle-detail table.steps")).to_contain_text("per_view_reprojection_error_in_pixels_after_refinement")
        pg.wait_for_timeout(300)  # the thumbnails take their place
        size = pg.evaluate("[document.documentElement.scrollWidth, document.documentElement.scrollHeight]")
        assert size[0] <= width and size[1] < 3 * height, size
        shot(pg, f"20-{width}x{height}-cycle-detail.png")
        assert log.errors == [], log.errors
    finally:
        context.close()


def test_nothing_is_operable_while_the_data_is_stale(cell: LiveCell, cycle_ids: list[int], browser: Any) -> None:
    """Both screens at once, through one outage of the service's HTTP (it takes seconds to be noticed)."""
    screens = [_sized(browser, w, h) for w, h in VIEWPORTS]
    try:
        before = []
        for _, pg, _ in screens:
            pg.goto(cell.url + "/")
            expect(pg.locator("body")).to_have_attribute("data-ready", "1")
            expect(pg.locator("#live")).to_have_text("live")
            expect(pg.locator("[data-command=clear]")).to_be_enabled()  # Aborted: Clear is the way out
            before.append(pg.eval_on_selector_all("[data-command]", "bs => bs.filter(b => !b.disabled).map(b => b.dataset.command)"))
        cell.stop_http()
        try:
            for (_, pg, _), (w, h) in zip(screens, VIEWPORTS, strict=True):
                expect(pg.locator("#live")).to_contain_text("STALE", timeout=12_000)
                note = pg.locator("#stale-note")
                expect(note).to_be_visible()
                expect(note).to_contain_text("no data from the cell controller")
                assert note.evaluate("n => n.getBoundingClientRect().bottom") <= h
                for sel in ("[data-command]", "#mode-apply", "#mode-select", "#token", "#token-save", "#ack-all", "#alarms-now [data-ack]"):
                    for i in range(pg.locator(sel).count()):
                        expect(pg.locator(sel).nth(i)).to_be_disabled()
                expect(pg.locator("[data-command=clear]")).to_have_attribute("title", re.compile("stale"))
                shot(pg, f"20-{w}x{h}-stale.png")
        finally:
            cell.start_http()
        for (_, pg, log), was in zip(screens, before, strict=True):
            expect(pg.locator("#live")).to_have_text("live", timeout=20_000)
            expect(pg.locator("#stale-note")).to_be_hidden()
            for cmd in was:
                expect(pg.locator(f"[data-command={cmd}]")).to_be_enabled()
            expect(pg.locator("#token")).to_be_enabled()
            expect(pg.locator("[data-command=start]")).to_be_disabled()  # the state's own rule again
            # The outage's failed requests are the browser's own reports; no script error.
            errors = [e for e in log.errors if not e.startswith("Failed to load resource")]
            assert errors == [], errors
    finally:
        for context, _, _ in screens:
            context.close()


@pytest.mark.parametrize(("width", "height"), VIEWPORTS, ids=lambda v: str(v))
def test_the_command_bars_lines_filling_or_emptying_do_not_move_the_page(
    cell: LiveCell, cycle_ids: list[int], browser: Any, width: int, height: int
) -> None:
    """The command bar's blocked line and message line keep their room when empty, and the message its padding when
    it is no alarm: a state change or a command's answer must not move the page under the operator's pointer (one
    alarm's Acknowledge onto the next one's). Chromium lays the overview out with each in turn."""
    context, pg, _ = _sized(browser, width, height)
    try:
        pg.goto(cell.url + "/")
        expect(pg.locator("body")).to_have_attribute("data-ready", "1")
        tops = pg.evaluate(
            """() => {
                const blocked = document.getElementById("blocked"), message = document.getElementById("message");
                const out = [];
                for (const [why, said, alarm] of [["", "", false], ["Start: acknowledge it first.", "Mode changed: PRODUCTION.", false],
                                                  ["", "Acknowledge refused (409): gone.", true], ["Start: acknowledge it first.", "", false]]) {
                    blocked.textContent = why;
                    message.textContent = said;
                    message.classList.toggle("is-alarm", alarm);
                    out.push(document.getElementById("main").getBoundingClientRect().top);
                }
                return out;
            }"""
        )
        assert len(set(tops)) == 1, tops
    finally:
        context.close()
