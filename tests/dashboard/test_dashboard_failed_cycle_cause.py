"""A cycle stopped by a device alarm names that alarm: in its record's error text and in the page's cycle detail.

The injected fault is the truth: the LK-G fake falls silent. The cycle's own laser read waits 5 s while the
watchdog sees the silence in well under a second, so the watchdog's 1101 (laser link lost) holds the cell and
is the first-out alarm. The record used to say only "the cell went to holding (hold by system)".
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
from dashboard_test_support import AUTH, LiveCell, browser_marks, settle, sim_config, to_execute, wait_cycle

from cellctl.domain import AlarmCode

pytestmark = browser_marks(240)

from playwright.sync_api import expect  # noqa: E402

WAIT_MS = 20_000


def test_the_failed_cycle_names_its_first_out_alarm(tmp_path: Path, page: Any) -> None:
    pg, log = page
    cfg = sim_config(
        **{
            "alarms.watchdog": {"period_s": 0.2, "timeout_s": 0.15, "miss_threshold": 2},
            "process.motion": {"grab_timeout_s": 1.0, "read_timeout_s": 5.0},
        }
    )
    with LiveCell(tmp_path, cfg) as live, httpx.Client(base_url=live.url, timeout=15.0) as client:
        to_execute(client)
        pg.goto(live.url + "/")
        expect(pg.locator("body")).to_have_attribute("data-ready", "1")
        live.service.extras["fakes"]["laser"].silence(count=None)
        r = client.post("/cycle", json={"recipe": "side-window", "part_id": "L-2"}, headers={**AUTH, "Idempotency-Key": "cause-l-2"})
        assert r.status_code == 202, r.text
        cid = int(r.json()["cycle_id"])
        rec = wait_cycle(client, cid)
        assert settle(client) == "HELD"
        stop = client.get("/alarms").json()["stop_reason"]
        assert stop is not None and stop["code"] == int(AlarmCode.LASER_LOST), stop  # the watchdog's, as set up
        assert rec["state"] == "failed" and rec["result"]["error_code"] == stop["code"], rec
        # the record: the old wording first (other readers match it), then the first-out alarm's code and message
        assert rec["error"].startswith("stopped: the cell went to holding (hold by system)"), rec["error"]
        assert f"alarm {stop['code']} " in rec["error"] and stop["message"] in rec["error"], rec["error"]
        # the page's detail shows the code as a fact and the record's text as its problem line
        pg.goto(f"{live.url}/#/cycles/{cid}")
        detail = pg.locator("#cycle-detail")
        expect(detail.locator("h2")).to_have_text(f"Cycle {cid}: failed", timeout=WAIT_MS)
        code_fact = detail.locator(".facts .pair").filter(has=pg.locator("dt", has_text="Error code")).locator("dd")
        expect(code_fact).to_have_text(str(stop["code"]))
        expect(detail.locator(".problems")).to_have_text(rec["error"])
        assert not log.errors, log.errors
