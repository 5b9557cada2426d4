"""With [api] open_reads = false the dashboard's images (the last image, the filmstrip, a cycle's
thumbnails) load with the entered token, and one refused for want of a token says so: a real
headless Chromium against the real served cell."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from dashboard_test_support import AUTH, TOKEN, LiveCell, PageLog, browser_marks, install_cycles, sim_config

pytestmark = browser_marks(120)

LOADED = "img => img.complete && img.naturalWidth > 0"


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveCell]:
    with LiveCell(tmp_path_factory.mktemp("token-images-cell"), sim_config(api={"open_reads": False})) as live:
        yield live


@pytest.fixture(scope="module")
def cycle_id(cell: LiveCell) -> int:
    """One installed cycle with images, run by a client that sends the token on every call."""
    with httpx.Client(base_url=cell.url, timeout=15.0, headers=AUTH) as c:
        return int(install_cycles(c, "token-images", [("P-IMG", "C-IMG")])[0]["id"])


def _with_token(pg: Any, cell: LiveCell, token: str) -> None:
    from playwright.sync_api import expect

    pg.goto(cell.url + "/")
    expect(pg.locator("body")).to_have_attribute("data-ready", "1")
    pg.fill("#token", token)
    pg.click("#token-save")


def test_the_images_load_with_the_token_under_closed_reads(cell: LiveCell, cycle_id: int, page: tuple[Any, PageLog]) -> None:
    from playwright.sync_api import expect

    pg, log = page
    statuses: dict[str, int] = {}
    pg.on("response", lambda r: statuses.__setitem__(r.url.split("?")[0].removeprefix(cell.url), r.status))
    _with_token(pg, cell, TOKEN)
    last = pg.locator("#last-image")
    expect(last).to_have_attribute("data-cycle", str(cycle_id), timeout=15_000)
    pg.wait_for_function(LOADED, arg=last.element_handle())
    with pg.expect_popup() as opened:  # the full-size image opens in a tab, read with the token too
        pg.click("#last-image-link")
    tab = opened.value
    tab.wait_for_url("blob:**")
    tab.wait_for_function("() => document.images.length === 1 && document.images[0].naturalWidth > 0")
    tab.close()
    film = pg.locator(f"#filmstrip [data-cycle='{cycle_id}'] img")
    pg.wait_for_function(LOADED, arg=film.element_handle())
    pg.goto(f"{cell.url}/#/cycles/{cycle_id}")
    thumb = pg.locator("#cycle-detail .thumbs img").first
    pg.wait_for_function(LOADED, arg=thumb.element_handle())
    assert pg.evaluate("img => img.naturalWidth", thumb.element_handle()) == 320
    thumbs = [u for u in statuses if u.startswith("/dashboard/thumbs/")]
    assert thumbs and all(statuses[u] == 200 for u in thumbs), statuses
    refused = "Failed to load resource: the server responded with a status of 401 (Unauthorized)"
    assert [e for e in log.errors if e != refused] == [], log.errors  # the 401s: the reads before the token
    # Shown from a blob: URL that is revoked once the picture loaded (the page keeps no blob).
    src = str(thumb.get_attribute("src"))
    assert src.startswith("blob:"), src
    revoked = pg.evaluate("url => fetch(url).then(() => false, () => true)", src)
    assert revoked, "the blob URL of a loaded image is revoked"


def test_an_image_refused_for_want_of_a_token_says_so(cell: LiveCell, cycle_id: int, page: tuple[Any, PageLog]) -> None:
    pg, _ = page
    _with_token(pg, cell, "not-the-token")
    name = httpx.get(f"{cell.url}/cycles/{cycle_id}", headers=AUTH, timeout=15.0).json()["images"][-1]["name"]
    failed = pg.evaluate(
        """async (url) => {
            const { showImage } = await import("/ui/images.js");
            const img = document.createElement("img");
            const error = new Promise((done) => img.addEventListener("error", () => done(true)));
            showImage(img, url);
            await error;
            return { failed: img.dataset.failed, title: img.title, src: img.getAttribute("src") };
        }""",
        f"/dashboard/thumbs/{cycle_id}/{name}?width=240",
    )
    assert failed == {"failed": "token", "title": "This image needs the operator token: enter it above.", "src": None}
    # The page as a whole is in the same state: its reads are refused until a valid token is entered.
    pg.wait_for_selector("#stale-note:not([hidden])")
    assert "enter the operator token" in pg.locator("#stale-note").inner_text()
