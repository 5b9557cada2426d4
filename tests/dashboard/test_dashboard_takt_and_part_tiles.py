"""The overview's "Part / car" tile and takt chart in a real headless Chromium against the simulated cell: with cycles
queued and none running (Hold during a cycle), the tile's "last:" names the newest cycle that ended, not a queued
one, with the queue's length beside it; the takt chart's headline and median count the good parts only (the failed
cycle's partial time is drawn, not counted), so the chart agrees with the shift table's "Takt (median)".
Truth: the cycle records (GET /cycles) and GET /status over httpx."""

from __future__ import annotations

import statistics
import time
from pathlib import Path
from typing import Any

import httpx
from dashboard_test_support import AUTH, LiveCell, PageLog, browser_marks, chromium_missing_reason, install_cycles, settle, shot

pytestmark = browser_marks(180)
if not chromium_missing_reason():
    from playwright.sync_api import Page, expect

ENDED = ("done", "failed", "interrupted")


def test_held_with_cycles_queued_the_tiles_name_the_last_ended_part_and_the_takt_of_good_parts(
    tmp_path: Path, page: tuple[Page, PageLog]
) -> None:
    pg, log = page
    with LiveCell(tmp_path) as live, httpx.Client(base_url=live.url, timeout=60.0) as client:
        install_cycles(client, "takt", [("T-1", "TC-1"), ("T-2", "TC-2")])
        pg.goto(live.url + "/")
        expect(pg.locator("body")).to_have_attribute("data-ready", "1")
        expect(pg.locator("#part")).to_have_text("last: T-2 / TC-2")
        ids = []
        for i in range(4):  # queued back to back; the first starts, Hold stops it, three wait
            r = client.post("/cycle", json={"recipe": "side-window", "part_id": f"H-{i}", "car_id": f"HC-{i}"},
                            headers={**AUTH, "Idempotency-Key": f"held-{i}"})  # fmt: skip
            assert r.status_code == 202, r.text
            ids.append(int(r.json()["cycle_id"]))
        end = time.monotonic() + 30
        while client.get("/status").json()["current_cycle"] is None and time.monotonic() < end:
            time.sleep(0.02)
        time.sleep(0.3)
        assert client.post("/commands/hold", headers=AUTH).status_code == 200
        assert settle(client) == "HELD"
        end = time.monotonic() + 30
        while client.get(f"/cycles/{ids[0]}").json()["state"] not in ENDED and time.monotonic() < end:
            time.sleep(0.05)
        records: list[dict[str, Any]] = client.get("/cycles").json()
        status = client.get("/status").json()
        assert status["current_cycle"] is None and status["queued_cycles"] == 3, status
        by_id = {int(r["id"]): r for r in records}
        assert by_id[ids[0]]["state"] == "failed" and [by_id[i]["state"] for i in ids[1:]] == ["queued"] * 3, records
        # the newest cycle that ended, from the records
        last = max((r for r in records if r["state"] in ENDED), key=lambda r: int(r["id"]))
        assert last["part_id"] == "H-0", last
        expect(pg.locator("#part")).to_have_text(f"last: {last['part_id']} / {last['car_id']}")
        expect(pg.locator("#part-queued")).to_have_text(f"{status['queued_cycles']} queued")
        # the takt: the good parts' cycle times (the failed cycle has a partial time of its own)
        failed_time = (by_id[ids[0]].get("result") or {}).get("cycle_time_s")
        assert isinstance(failed_time, float) and failed_time > 0, by_id[ids[0]]
        good = sorted((r for r in records if r["state"] == "done" and r["result"].get("part_ok") is not False), key=lambda r: int(r["id"]))
        times = [float(r["result"]["cycle_time_s"]) for r in good]
        assert len(times) == 2 and abs(failed_time - times[-1]) > 0.01, (times, failed_time)
        chart = pg.locator("#cycle-time-chart [data-axis=cycle_time_s]")
        expect(chart.locator(".chart-value")).to_have_text(f"{times[-1]:.2f}")
        median = statistics.median(times)
        label = chart.locator("svg").get_attribute("aria-label") or ""
        assert f"latest {times[-1]:.2f} s" in label and f"median {median:.2f} s" in label, label
        expect(pg.locator("#shifts tr[data-shift=current]")).to_contain_text(f"{median:.2f} s")
        expect(chart).to_have_attribute("data-points", "3")  # the failed cycle drawn
        expect(chart).to_have_attribute("data-counted", "2")  # and not counted
        shot(pg, "overview-held-with-queue.png")
    assert log.errors == [], log.errors
