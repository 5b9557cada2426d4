"""The dashboard's shift table across a daylight saving change: the page sends its IANA time zone and every shift's
bounds follow that zone's offset at the time (a night shift over the spring change lasts 7 h, over the autumn one
9 h), so each shift counts the cycles that ended in it on the plant's clock. A zone the service's tz database does not
know is refused naming the field; a browser that names no zone still gets one offset for every shift.

Peers: the OS's tz database through zoneinfo (the shifts' bounds and which shift a cycle's end falls in are computed
here from it alone) and a headless Chromium given the zone by playwright's ``timezone_id``. The server's clock is
frozen at a chosen instant after each change in Europe/Berlin and America/New_York (2026); the cycles are written into
the store beforehand, one every 20 minutes over the two days before."""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from typing import Any
from zoneinfo import ZoneInfo

import httpx
import pytest
from dashboard_test_support import LiveCell, PageLog, chromium_missing_reason, sim_config

from cellctl.api import dashboard
from cellctl.store import CellStore, CycleRequest

pytestmark = pytest.mark.timeout(240)
BROWSER_MISSING = chromium_missing_reason()

STARTS = (6, 14, 22)  # the default shift starts, local hours
COUNT = 6  # two days of shifts: the change lies in them

# (zone, the instant of the change, the server's now: a few hours into the afternoon shift after it)
SCENARIOS = {
    "berlin-spring": ("Europe/Berlin", datetime(2026, 3, 29, 1, 0, tzinfo=UTC), datetime(2026, 3, 29, 15, 0, tzinfo=UTC)),
    "berlin-autumn": ("Europe/Berlin", datetime(2026, 10, 25, 1, 0, tzinfo=UTC), datetime(2026, 10, 25, 14, 0, tzinfo=UTC)),
    "new-york-spring": ("America/New_York", datetime(2026, 3, 8, 7, 0, tzinfo=UTC), datetime(2026, 3, 8, 19, 0, tzinfo=UTC)),
    "new-york-autumn": ("America/New_York", datetime(2026, 11, 1, 6, 0, tzinfo=UTC), datetime(2026, 11, 1, 20, 0, tzinfo=UTC)),
}
SPACING = timedelta(minutes=20)
SPAN = timedelta(hours=52)  # cycles end every SPACING over the SPAN before each scenario's now


def _ends(now: datetime) -> list[datetime]:
    n = int(SPAN / SPACING)
    return [now - SPAN + k * SPACING + timedelta(minutes=7) for k in range(n)]


def _oracle(zone: ZoneInfo, now: datetime) -> list[tuple[datetime, datetime]]:
    """The current shift and the ones before it, newest first, (start, end) in UTC: the local 06:00, 14:00 and 22:00
    of each day, each converted by zoneinfo with the offset the zone has on that day and hour."""
    today = now.astimezone(zone).date()
    days = [today + timedelta(days=d) for d in range(-4, 2)]
    bounds = sorted(datetime(d.year, d.month, d.day, h, tzinfo=zone).astimezone(UTC) for d in days for h in STARTS)
    i = max(k for k, b in enumerate(bounds) if b <= now)
    return [(bounds[k], bounds[k + 1]) for k in range(i, i - COUNT, -1)]


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveCell]:
    """The simulated cell over a store holding the scenarios' cycles, each done and good, ending at the test's times."""
    workdir = tmp_path_factory.mktemp("dashboard-shifts-dst")
    db = workdir / "var" / "cellctl.db"
    db.parent.mkdir(parents=True)
    at = [datetime.now(UTC)]
    with CellStore.open(db, synchronous="NORMAL", clock=lambda: at[0]) as store:
        for name, (_zone, _change, now) in sorted(SCENARIOS.items(), key=lambda s: s[1][2]):
            for k, end in enumerate(_ends(now)):
                at[0] = end - timedelta(seconds=40)
                cid = store.submit_cycle(CycleRequest("side-window", f"{name}-{k}"), scope="t", key=f"{name}-{k}", actor="t").cycle.id
                store.start_cycle(cid)
                at[0] = end
                store.complete_cycle(cid, result={"part_ok": True, "cycle_time_s": 40.0})
    config = sim_config(**{"store.retention": {"cycles_days": "forever"}})  # the cycles of 2026 are kept whenever this runs
    with LiveCell(workdir, config) as live:
        yield live


@pytest.fixture()
def frozen(monkeypatch: pytest.MonkeyPatch) -> Any:
    """``frozen(t)``: the dashboard's clock (``datetime.now``) reads ``t`` until the test ends."""

    def freeze(t: datetime) -> None:
        monkeypatch.setattr(dashboard, "datetime", type("FrozenDatetime", (datetime,), {"now": classmethod(lambda cls, tz=None: t.astimezone(tz))}))

    return freeze


@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_each_shift_follows_the_zones_offset_at_its_time_and_counts_what_ended_in_it(
    cell: LiveCell, client: httpx.Client, frozen: Any, scenario: str
) -> None:
    name, change, now = SCENARIOS[scenario]
    zone = ZoneInfo(name)
    assert (change - timedelta(minutes=1)).astimezone(zone).utcoffset() != change.astimezone(zone).utcoffset()  # a change
    frozen(now)
    r = client.get("/dashboard/shifts", params={"tz": name, "count": COUNT})
    assert r.status_code == 200, r.text
    body = r.json()
    expected = _oracle(zone, now)
    got = [(datetime.fromisoformat(s["start_utc"]), datetime.fromisoformat(s["end_utc"])) for s in body["shifts"]]
    assert got == expected, (got, expected)
    assert [s["start_local"] for s in body["shifts"]] == [s.astimezone(zone).strftime("%Y-%m-%d %H:%M") for s, _ in expected]
    assert expected[-1][0] < change < expected[0][0]  # the shifts span the change
    # The night shift over the change is an hour shorter (spring) or longer (autumn) than 8 h.
    spanning = next(e - s for s, e in expected if s < change < e)
    assert spanning == timedelta(hours=7 if "spring" in scenario else 9), spanning
    # Each cycle counts in the shift whose bounds, on the plant's clock, hold its end.
    ends = _ends(now)
    truth = Counter(next((i for i, (s, e) in enumerate(expected) if s <= t < e), None) for t in ends)
    assert [(s["good"], s["not_ok"]) for s in body["shifts"]] == [(truth[i], 0) for i in range(COUNT)], truth
    assert body["tz"] == name and body["tz_offset_min"] == now.astimezone(zone).utcoffset() // timedelta(minutes=1)


def test_a_shift_start_the_spring_change_skips_begins_when_the_clock_jumps_past_it(client: httpx.Client, frozen: Any) -> None:
    frozen(datetime(2026, 3, 29, 15, 0, tzinfo=UTC))  # Berlin: 02:00 CET became 03:00 CEST at 01:00 UTC
    r = client.get("/dashboard/shifts", params={"tz": "Europe/Berlin", "starts": "02:30,12:00", "count": 3})
    assert r.status_code == 200, r.text
    shifts = [(s["start_local"], s["start_utc"], s["end_utc"]) for s in r.json()["shifts"]]
    assert shifts == [
        ("2026-03-29 12:00", "2026-03-29T10:00:00+00:00", "2026-03-30T00:30:00+00:00"),
        ("2026-03-29 03:00", "2026-03-29T01:00:00+00:00", "2026-03-29T10:00:00+00:00"),  # 02:30 never showed
        ("2026-03-28 12:00", "2026-03-28T11:00:00+00:00", "2026-03-29T01:00:00+00:00"),
    ], shifts


def test_an_unknown_zone_is_refused_naming_the_field_and_without_one_the_offset_holds(
    client: httpx.Client, frozen: Any
) -> None:
    now = SCENARIOS["berlin-spring"][2]
    frozen(now)
    for bad in ("Mars/Olympus", "Europe", "europe/berlin", "../etc/passwd"):
        r = client.get("/dashboard/shifts", params={"tz": bad})
        assert r.status_code == 422, (bad, r.text)
        assert "'tz'" in r.json()["detail"], r.text
    # A browser that names no zone: its offset now, for every shift (the fallback).
    r = client.get("/dashboard/shifts", params={"tz_offset_min": 120, "count": COUNT})
    assert r.status_code == 200, r.text
    assert r.json()["tz"] is None and r.json()["tz_offset_min"] == 120
    for s in r.json()["shifts"]:
        assert (datetime.fromisoformat(s["start_utc"]) + timedelta(minutes=120)).hour in STARTS, s


@pytest.mark.skipif(BROWSER_MISSING is not None, reason=BROWSER_MISSING or "")
def test_the_browser_sends_its_zone_and_shows_each_shifts_hours_on_its_own_clock(
    cell: LiveCell, browser: Any, frozen: Any
) -> None:
    from playwright.sync_api import expect

    name, _change, now = SCENARIOS["new-york-spring"]
    zone = ZoneInfo(name)
    frozen(now)
    expected = _oracle(zone, now)[:3]  # the page shows the current shift and the two before it
    ends = _ends(now)
    context = browser.new_context(viewport={"width": 1920, "height": 1080}, timezone_id=name)
    pg = context.new_page()
    log = PageLog()
    pg.on("request", lambda r: log.requests.append(r.url))
    pg.on("pageerror", lambda e: log.errors.append(str(e)))
    try:
        pg.goto(cell.url + "/")
        expect(pg.locator("body")).to_have_attribute("data-ready", "1")
        rows = pg.locator("#shifts tbody tr")
        labels = [f"{s.astimezone(zone):%Y-%m-%d %H:%M} to {e.astimezone(zone):%H:%M}" for s, e in expected]
        for i, label in enumerate(labels):
            expect(rows.nth(i).locator("th")).to_contain_text(label)
            good = sum(1 for t in ends if expected[i][0] <= t < expected[i][1])
            expect(rows.nth(i).locator("[data-count=good]")).to_have_text(str(good))
        asked = [u for u in log.requests if "/dashboard/shifts" in u]
        assert asked and all(re.search(r"[?&]tz=America%2FNew_York(&|$)", u) for u in asked), asked
        assert not log.errors, log.errors
    finally:
        context.close()
