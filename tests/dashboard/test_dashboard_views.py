"""The dashboard's scripts are native ES modules (app.js the entry point): the page names every one
of them, each is served as JavaScript, and every view (and a cycle's detail) opens in a real
headless Chromium, by its tab and by its address, without a script error or warning, a failed
load or a request leaving the cell controller."""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any
from urllib.parse import urlsplit

import httpx
import pytest
from dashboard_test_support import (
    LiveCell,
    PageLog,
    chromium_missing_reason,
    install_cycles,
)

from cellctl.api.dashboard import STATIC_DIR

pytestmark = pytest.mark.timeout(120)

_missing = chromium_missing_reason()
needs_chromium = pytest.mark.skipif(_missing is not None, reason=_missing or "")
if _missing is None:
    from playwright.sync_api import Page, expect

PAGES = ("overview", "cycles", "alarms", "calibration", "commissioning")
MODULES = sorted(p.name for p in STATIC_DIR.glob("*.js"))


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveCell]:
    with LiveCell(tmp_path_factory.mktemp("dashboard-views")) as live:
        yield live


@pytest.fixture(scope="module")
def cycle_id(client: httpx.Client) -> int:
    """One installed cycle, so the trends, the filmstrip, the history and a detail have something to show."""
    return int(install_cycles(client, "views", [("P-VIEWS", "C-VIEWS")])[0]["id"])


def test_the_page_names_every_module_and_each_is_served_as_javascript(client: httpx.Client) -> None:
    html = client.get("/").text
    entry = re.findall(r'<script type="module" src="/ui/([^"]+)"></script>', html)
    preloaded = re.findall(r'<link rel="modulepreload" href="/ui/([^"]+)">', html)
    assert entry == ["app.js"]
    assert sorted(set(entry + preloaded)) == MODULES, "index.html preloads every module in static/"
    assert "<script src=" not in html, "no classic scripts: everything is a module"
    for name in MODULES:
        r = client.get(f"/ui/{name}")
        assert r.status_code == 200, name
        assert "javascript" in r.headers["content-type"], (name, r.headers["content-type"])
        # Imports are relative to the module's own folder (served under /ui/), never absolute.
        for spec in re.findall(r'\bfrom "([^"]+)";', r.text):
            assert spec.startswith("./") and spec[2:] in MODULES, (name, spec)


def _show(pg: Page, name: str) -> None:
    expect(pg.locator(f"#page-{name}")).to_be_visible()
    expect(pg.locator(f"nav a[data-page={name}]")).to_have_attribute("aria-current", "page")
    for other in PAGES:
        if other != name:
            expect(pg.locator(f"#page-{other}")).to_be_hidden()


@needs_chromium
def test_every_view_opens_without_a_script_error(cell: LiveCell, cycle_id: int, page: tuple[Page, PageLog]) -> None:
    pg, log = page
    # A view that throws while it refreshes is logged as a warning ("refresh ... failed"), not an error.
    warnings: list[str] = []
    pg.on("console", lambda m: warnings.append(m.text) if m.type == "warning" else None)
    pg.goto(cell.url + "/")
    expect(pg.locator("body")).to_have_attribute("data-ready", "1")
    _show(pg, "overview")
    expect(pg.locator(f"#filmstrip [data-cycle='{cycle_id}']")).to_contain_text("P-VIEWS")
    expect(pg.locator("#trend-charts [data-axis=dx_mm]")).to_have_attribute("data-points", "1")
    # By the tabs, without a reload.
    pg.click("nav a[data-page=cycles]")
    _show(pg, "cycles")
    expect(pg.locator(f"#cycle-table tbody tr[data-cycle='{cycle_id}']")).to_be_visible()
    pg.click(f"#cycle-table tbody tr[data-cycle='{cycle_id}'] a")
    expect(pg.locator("#cycle-detail h2")).to_have_text(f"Cycle {cycle_id}: done")
    pg.click("nav a[data-page=alarms]")
    _show(pg, "alarms")
    expect(pg.locator("#alarms-history > *")).to_have_count(1)
    pg.click("nav a[data-page=calibration]")
    _show(pg, "calibration")
    expect(pg.locator("#cal-problems")).not_to_be_empty()
    pg.click("nav a[data-page=commissioning]")
    _show(pg, "commissioning")
    expect(pg.locator("#comm-proc-table [data-start]").first).to_be_visible()
    expect(pg.locator("#comm-versions > *")).to_have_count(1)
    pg.click("nav a[data-page=overview]")
    _show(pg, "overview")
    assert log.loads == 1
    # Every module was loaded, from the package.
    loaded = {urlsplit(u).path for u in log.requests}
    assert {f"/ui/{m}" for m in MODULES} <= loaded, sorted({f"/ui/{m}" for m in MODULES} - loaded)
    # By the address, each a fresh load.
    for address, name in (
        (f"/#/cycles/{cycle_id}", "cycles"),
        ("/#/alarms", "alarms"),
        ("/#/calibration", "calibration"),
        ("/#/commissioning", "commissioning"),
        ("/#/no-such-page", "overview"),
    ):
        pg.goto(cell.url + address)
        expect(pg.locator("body")).to_have_attribute("data-ready", "1")
        _show(pg, name)
    expect(pg.locator("#live")).to_have_text("live")
    assert pg.evaluate("typeof window.cellctlDashboard.loadedAt") == "number"
    assert log.foreign() == [], log.foreign()
    assert log.errors == [], log.errors
    assert warnings == [], warnings


@needs_chromium
def test_an_answer_that_arrives_late_never_overwrites_a_newer_one(
    cell: LiveCell, cycle_id: int, page: tuple[Page, PageLog]
) -> None:
    """The history is asked for twice, unfiltered and then 'failed' only; the unfiltered answer is held
    back until the filtered one is shown. It arrives last and is dropped: the table stays filtered."""
    pg, log = page
    pg.goto(cell.url + "/#/cycles")
    expect(pg.locator("body")).to_have_attribute("data-ready", "1")
    row = pg.locator(f"#cycle-table tbody tr[data-cycle='{cycle_id}']")
    expect(row).to_have_count(1)
    held: list[Any] = []
    pg.route(re.compile(r"/cycles\?limit=200$"), lambda route: held.append(route))
    pg.dispatch_event("#filter-state", "change")  # asks again, unfiltered: held
    while not held:
        pg.wait_for_timeout(20)
    pg.select_option("#filter-state", "failed")
    expect(row).to_have_count(0)
    with pg.expect_response(lambda r: r.url.endswith("/cycles?limit=200")) as late:
        for route in held:
            route.continue_()
    late.value.finished()
    pg.evaluate("() => new Promise((done) => setTimeout(done, 300))")  # its answer has been read and dropped
    expect(row).to_have_count(0)
    assert log.errors == [], log.errors
