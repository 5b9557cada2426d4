"""Fixtures of the dashboard's browser tests: one Chromium per module, a fresh page per test, the REST client."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from dashboard_test_support import CHROMIUM, CHROMIUM_ARGS, LiveCell, PageLog


@pytest.fixture(scope="module")
def client(cell: LiveCell) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=cell.url, timeout=15.0) as c:
        yield c


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    from playwright.sync_api import expect, sync_playwright

    expect.set_options(timeout=10_000)  # a page's assertions wait this long: CI shares two cores with a worker
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, timeout=30_000)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture()
def page(browser: Any) -> Iterator[tuple[Any, PageLog]]:
    """A 1920 x 1080 page whose requests, console errors and full loads are logged."""
    context = browser.new_context(viewport={"width": 1920, "height": 1080})
    pg = context.new_page()
    log = PageLog()
    pg.on("request", lambda r: log.requests.append(r.url))
    pg.on("console", lambda m: log.errors.append(m.text) if m.type == "error" else None)
    pg.on("pageerror", lambda e: log.errors.append(str(e)))
    pg.on("load", lambda _: setattr(log, "loads", log.loads + 1))
    pg.set_default_timeout(15_000)
    try:
        yield pg, log
    finally:
        context.close()
