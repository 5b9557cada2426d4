"""With [api] open_reads = false the dashboard reads (its settings, the status, the live /events stream) with
the operator token once it is entered: a real headless Chromium against the real served cell."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from dashboard_test_support import TOKEN, LiveCell, PageLog, browser_marks, sim_config

pytestmark = browser_marks(120)


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveCell]:
    with LiveCell(tmp_path_factory.mktemp("closed-reads-cell"), sim_config(api={"open_reads": False})) as live:
        yield live


def test_the_dashboard_reads_and_streams_with_the_entered_token(cell: LiveCell, page: tuple[Any, PageLog]) -> None:
    from playwright.sync_api import expect

    pg, log = page
    statuses: dict[str, int] = {}
    pg.on("response", lambda r: statuses.__setitem__(r.url.split("?")[0].removeprefix(cell.url), r.status))
    pg.goto(cell.url + "/")
    expect(pg.locator("body")).to_have_attribute("data-ready", "1")
    assert statuses.get("/dashboard/config") == 401  # no token yet: closed reads refuse the page's reads
    pg.fill("#token", TOKEN)
    pg.click("#token-save")
    # the event stream reconnects with the token: live data, and the status it carries
    expect(pg.locator("#live")).to_have_text("live", timeout=15_000)
    expect(pg.locator("#state")).not_to_have_text("", timeout=15_000)
    assert statuses.get("/events") == 200 and statuses.get("/status") == 200, statuses
    pg.reload()  # the token stays in this tab: everything reads at once, settings included
    expect(pg.locator("body")).to_have_attribute("data-ready", "1")
    expect(pg.locator("#live")).to_have_text("live", timeout=15_000)
    assert statuses.get("/dashboard/config") == 200, statuses
    assert "Could not read the dashboard settings" not in pg.locator("body").inner_text()
