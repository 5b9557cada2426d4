"""The stale-data mark counts the silence on the page's monotonic clock, not the workstation's wall clock.

A workstation whose clock NTP steps back an hour just as the cell controller falls silent: reckoned on
Date.now(), the last message would be an hour in the future for an hour, so the page would read "live" and
leave its commands on while nothing came. Peer: Chromium driven by Playwright, whose clock steps the page's
Date alone (``set_system_time``); the service is real and its HTTP server is taken away as a lost network would.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from typing import Any

import pytest
from dashboard_test_support import LiveCell, browser_marks

pytestmark = browser_marks(120)  # skipped only where Chromium is missing (CI installs it)


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveCell]:
    with LiveCell(tmp_path_factory.mktemp("stale-clock-cell")) as live:
        yield live


def test_a_workstation_clock_stepped_back_does_not_keep_silent_data_live(cell: LiveCell, browser: Any) -> None:
    from playwright.sync_api import expect

    context = browser.new_context(viewport={"width": 1920, "height": 1080})
    context.clock.install(time=datetime.now(timezone.utc))  # the page's clocks under Playwright's hand, running
    pg = context.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.set_default_timeout(15_000)
    try:
        pg.goto(cell.url + "/")
        expect(pg.locator("body")).to_have_attribute("data-ready", "1")
        expect(pg.locator("#live")).to_have_text("live")
        before = pg.evaluate("[Date.now(), performance.now()]")
        context.clock.set_system_time(datetime.now(timezone.utc) - timedelta(hours=1))  # NTP steps the clock back
        after = pg.evaluate("[Date.now(), performance.now()]")
        assert after[0] < before[0] - 3_000_000 and after[1] >= before[1], (before, after)  # the wall clock alone stepped
        cell.stop_http()
        try:
            expect(pg.locator("#live")).to_contain_text("STALE", timeout=12_000)
            expect(pg.locator("body")).to_have_class(re.compile(r"\bstale\b"))
            expect(pg.locator("#stale-note")).to_contain_text("Commands and forms are off")
            assert re.search(r"\((\d+) s ago\)", pg.locator("#stale-note").text_content() or ""), "the note's age"
        finally:
            cell.start_http()
        expect(pg.locator("#live")).to_have_text("live", timeout=20_000)
        expect(pg.locator("body")).not_to_have_class(re.compile(r"\bstale\b"))
    finally:
        context.close()
    assert errors == [], errors
