"""The dashboard's calibration verdict in a real headless Chromium against the simulated cell serving a versioned
calibration set built in the test: a recipe that is not ready is shown not ready in the header tile and on the
calibration page, named with its problems (the service's own lines, each naming the command); the due dates are
the parts' own expiry as the service states it (never re-derived from calibration.max_age_days); the page, left
open, follows the service when a recipe's readiness changes or a part expires. Truth: GET /calibration and
GET /status over httpx, and the dates the test calibrated the parts at."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import httpx
import pytest
from calibration_set_support import CELL_PARTS, RECIPE_PARTS, commit
from dashboard_test_support import LiveCell, browser_marks, chromium_missing_reason, shot, sim_config

from cellctl.calibration.calibration_set import CalibrationStore

pytestmark = browser_marks(120)
if not chromium_missing_reason():
    from playwright.sync_api import Page, expect

def _laser_overdue_set(store: CalibrationStore) -> tuple[datetime, datetime, datetime]:
    """A ready set but for the laser, recorded valid 30 days and calibrated 31.5 days ago; the camera valid 30 days
    since 10 days ago, the rest an hour old (90 days). Returns when the camera, the laser and the rest were calibrated."""
    now = datetime.now(timezone.utc)
    camera_at, laser_at, rest_at = now - timedelta(days=10), now - timedelta(days=31.5), now - timedelta(hours=1)
    commit(store, ("camera",), None, camera_at, valid_days=30.0)
    commit(store, ("hand_eye",), None, rest_at)
    commit(store, ("laser",), None, laser_at, valid_days=30.0)
    commit(store, RECIPE_PARTS, None, rest_at)
    commit(store, RECIPE_PARTS, "door-window", rest_at)
    return camera_at, laser_at, rest_at


def serve(tmp_path: Path, store: CalibrationStore) -> LiveCell:
    """The simulated cell on the set at ``store`` (config/sim.toml: calibration.max_age_days = 90)."""
    cfg = sim_config(calibration={"source": "set", "auto_calibrate_in_sim": False, "directory": str(store.root)})
    assert cfg.calibration.max_age_days == 90.0
    return LiveCell(tmp_path / "cell", cfg)


@pytest.fixture()
def utc_page(browser: Any) -> Iterator[tuple[Page, list[str]]]:
    """A 1920 x 1080 page in UTC (the dates it shows are UTC dates), and its script errors."""
    context = browser.new_context(viewport={"width": 1920, "height": 1080}, timezone_id="UTC")
    pg = context.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    pg.set_default_timeout(15_000)
    try:
        yield pg, errors
    finally:
        context.close()


def open_calibration(pg: Page, url: str) -> None:
    pg.goto(url + "/#/calibration")
    expect(pg.locator("body")).to_have_attribute("data-ready", "1")
    expect(pg.locator("#live")).to_have_text("live")


def wait_for(client: httpx.Client, what: str, ok: Any, deadline_s: float = 60.0) -> dict[str, Any]:
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        cal = client.get("/calibration").json()
        if ok(cal):
            return dict(cal)
        time.sleep(0.2)
    raise AssertionError(f"{what} not within {deadline_s} s: {client.get('/calibration').json()}")


def test_a_recipe_not_ready_is_named_with_its_problems_and_the_open_page_follows_its_teaching(
    tmp_path: Path, utc_page: tuple[Page, list[str]]
) -> None:
    """The laser redone and the first recipe re-taught (the README's steps without --recipe): the door window's
    teaching was computed with the old laser. The header said "ready" and the page "Ready for production: the set
    is complete, valid and in date"; then the door window is re-taught while the page stays open."""
    pg, errors = utc_page
    store = CalibrationStore(tmp_path / "calibration")
    t0 = datetime.now(timezone.utc) - timedelta(hours=2)
    commit(store, CELL_PARTS, None, t0)
    commit(store, RECIPE_PARTS, "door-window", t0)
    commit(store, ("laser",), None, t0 + timedelta(minutes=10))
    commit(store, RECIPE_PARTS, None, t0 + timedelta(minutes=20))
    with serve(tmp_path, store) as live, httpx.Client(base_url=live.url, timeout=15.0) as client:
        cal = client.get("/calibration").json()
        recipes = cal["current"]["recipes"]
        door = recipes["door-window"]["problems"]
        assert recipes["door-window"]["ready"] is False and door and all("door-window" in line and "`cellctl " in line for line in door), recipes
        assert recipes["side-window"] == {"taught": True, "ready": True, "problems": []} and cal["problems"] == [], cal
        status = client.get("/status").json()["calibration"]
        assert status["recipes"]["door-window"] == {"ready": False, "problems": door}, status
        open_calibration(pg, live.url)
        # the header: not ready, naming the recipe and how many problems
        expect(pg.locator("#cal")).to_have_text(f"NOT READY: door-window ({len(door)})")
        assert "\n".join(door) in (pg.locator("#tile-cal").get_attribute("title") or "")
        # the page: the recipe named with each of its problems, the recipe that may run named as such
        problems = pg.locator("#cal-problems")
        expect(problems.locator("[data-recipe-problems=door-window] li")).to_have_text(door)
        expect(problems.locator("[data-recipe-problems=door-window] strong")).to_contain_text("door-window: not ready")
        expect(problems.locator("[data-ready=some]")).to_have_text("Ready for production: side-window.")
        expect(problems).not_to_contain_text("complete, valid and in date")
        expect(pg.locator("#cal-recipes [data-recipe=door-window] td").nth(1)).to_have_text("not ready")
        shot(pg, "calibration-recipe-not-ready.png")
        # re-taught while the page stays open (no cycle, no navigation): the page and the tile follow the service
        commit(store, RECIPE_PARTS, "door-window", datetime.now(timezone.utc))
        cal = wait_for(client, "door-window ready", lambda c: c["current"]["recipes"]["door-window"]["ready"])
        expect(problems).to_have_text("Ready for production: every recipe (side-window, door-window); the set is complete, valid and in date.")
        expect(pg.locator("#cal")).to_have_text(f"ready, set v{cal['current']['version']}")
        expect(pg.locator("#cal-recipes [data-recipe=door-window] td").nth(1)).to_have_text("ready")
    assert errors == [], errors


def test_due_dates_are_each_parts_own_expiry_not_the_configured_age(tmp_path: Path, utc_page: tuple[Page, list[str]]) -> None:
    """Parts recorded valid 30 days under a configuration that now says 90 (max_age_days): the camera is due 20 days
    from now, the laser 1.5 days overdue. The page dated every part calibrated + 90 days ("laser ... in 58 d")."""
    pg, errors = utc_page
    store = CalibrationStore(tmp_path / "calibration")
    camera_at, laser_at, rest_at = _laser_overdue_set(store)
    truth = {"camera": camera_at + timedelta(days=30), "laser": laser_at + timedelta(days=30),
             **{n: rest_at + timedelta(days=90) for n in ("hand_eye", "teaching", "pixel_map")}}  # fmt: skip
    with serve(tmp_path, store) as live, httpx.Client(base_url=live.url, timeout=15.0) as client:
        cal = client.get("/calibration").json()
        parts = cal["current"]["parts"]
        for name, due in truth.items():  # the service states the expiry the test recorded
            assert datetime.fromisoformat(parts[name]["expires_utc"]) == due, (name, parts[name])
        assert any(line.startswith("laser: expired on") for line in cal["problems"]), cal["problems"]
        open_calibration(pg, live.url)
        for name, due in truth.items():
            expect(pg.locator(f"#cal-parts td[data-due={name}]")).to_contain_text(f"{due:%Y-%m-%d}")
        laser_due = truth["laser"]
        overdue_days = math.floor((datetime.now(timezone.utc) - laser_due) / timedelta(days=1))
        assert overdue_days == 1
        expect(pg.locator("#cal-due-line")).to_contain_text(f"Due {laser_due:%Y-%m-%d}")
        expect(pg.locator("#cal-due-line")).to_contain_text("(overdue by 1 d): laser expires first")
        expect(pg.locator("#cal-due")).to_have_text(f"due {laser_due:%Y-%m-%d} (overdue by 1 d)")
        expect(pg.locator("#cal-problems")).to_contain_text("laser: expired on")
    assert errors == [], errors


def test_the_open_page_follows_a_part_expiring_and_says_overdue_without_a_day_count(
    tmp_path: Path, utc_page: tuple[Page, list[str]]
) -> None:
    """The camera's recorded validity ends about 20 s after the page opened; nothing else happens in the cell (no
    cycle, no navigation). The page kept "Ready for production" until the operator navigated, and a part minutes
    overdue read "overdue by 1 d"."""
    pg, errors = utc_page
    store = CalibrationStore(tmp_path / "calibration")
    start = datetime.now(timezone.utc)
    at = start - timedelta(hours=1)
    expires = start + timedelta(seconds=25)
    commit(store, ("camera",), None, at, valid_days=(expires - at) / timedelta(days=1))
    commit(store, CELL_PARTS[1:], None, at)
    commit(store, RECIPE_PARTS, "door-window", at)
    with serve(tmp_path, store) as live, httpx.Client(base_url=live.url, timeout=15.0) as client:
        cal = client.get("/calibration").json()
        assert cal["problems"] == [] and datetime.fromisoformat(cal["current"]["parts"]["camera"]["expires_utc"]) == expires, cal
        open_calibration(pg, live.url)
        expect(pg.locator("#cal-problems")).to_contain_text("Ready for production: every recipe")
        expect(pg.locator("#cal-due-line")).to_contain_text("camera expires first")
        assert datetime.now(timezone.utc) < expires, "the page opened too late to see the part expire"
        cal = wait_for(client, "the camera's expiry", lambda c: bool(c["problems"]))
        lines = cal["problems"]
        assert [line for line in lines if line.startswith("camera: expired on")] == lines, lines
        assert all(r["problems"] == lines for r in cal["current"]["recipes"].values()), cal["current"]["recipes"]
        # within a few status periods, without navigating
        expect(pg.locator("#cal-problems li")).to_have_text(lines)
        expect(pg.locator("#cal-problems")).not_to_contain_text("Ready for production")
        expect(pg.locator("#cal")).to_have_text(f"NOT READY ({len(lines)})")
        expect(pg.locator("#cal-due-line")).to_contain_text("(overdue): camera expires first")
        expect(pg.locator("#cal-due")).to_have_text(f"due {expires:%Y-%m-%d} (overdue)")
        shot(pg, "calibration-expired-while-open.png")
    assert errors == [], errors


def test_due_times_are_reckoned_on_the_services_clock_not_the_browsers(tmp_path: Path, browser: Any) -> None:
    """A workstation whose clock stands three days behind the cell controller's: the laser, expired 1.5 days ago by
    the service's clock, reads overdue (the browser's own clock made it "in 1 d"), and the camera, due in 20 days less
    the seconds the test takes, "in 19 d" (whole days; it read 22 d), in the header tile too."""
    store = CalibrationStore(tmp_path / "calibration")
    now, (camera_at, laser_at, _) = datetime.now(timezone.utc), _laser_overdue_set(store)
    context = browser.new_context(viewport={"width": 1920, "height": 1080}, timezone_id="UTC")
    context.clock.install(time=now - timedelta(days=3))  # the browser's clock, running from three days back
    pg = context.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.set_default_timeout(15_000)
    try:
        with serve(tmp_path, store) as live, httpx.Client(base_url=live.url, timeout=15.0) as client:
            cal = client.get("/calibration").json()
            served_at = datetime.fromisoformat(cal["now_utc"])
            assert abs(served_at - datetime.now(timezone.utc)) < timedelta(seconds=30), cal["now_utc"]
            laser_due = datetime.fromisoformat(cal["current"]["parts"]["laser"]["expires_utc"])
            assert laser_due == laser_at + timedelta(days=30)
            assert pg.evaluate("Date.now()") < (now - timedelta(days=2)).timestamp() * 1e3  # the page's clock is behind
            open_calibration(pg, live.url)
            expect(pg.locator("#cal-due-line")).to_contain_text(f"Due {laser_due:%Y-%m-%d}")
            expect(pg.locator("#cal-due-line")).to_contain_text("(overdue by 1 d): laser expires first")
            expect(pg.locator("#cal-due")).to_have_text(f"due {laser_due:%Y-%m-%d} (overdue by 1 d)")
            # Without the laser's part the camera is first: due in 20 days by the service's clock.
            commit(store, ("laser",), None, datetime.now(timezone.utc))
            wait_for(client, "the laser's new part", lambda c: c["current"]["parts"]["laser"]["status"] == "ok")
            pg.reload()
            expect(pg.locator("body")).to_have_attribute("data-ready", "1")
            camera_due = camera_at + timedelta(days=30)
            expect(pg.locator("#cal-due-line")).to_contain_text(f"Due {camera_due:%Y-%m-%d}")
            expect(pg.locator("#cal-due-line")).to_contain_text("(in 19 d): camera expires first")
            expect(pg.locator("#cal-due")).to_have_text(f"due {camera_due:%Y-%m-%d} (19 d)")
    finally:
        context.close()
    assert errors == [], errors
