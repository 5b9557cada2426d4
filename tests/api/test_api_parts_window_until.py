"""An MES whose clock runs ahead of the cell's: `GET /parts` applies `until` no later than the cell's clock and answers
the bound it applied, so an install ending after the query falls in the next window (from that bound) instead of in
none. The peers: the REST API (httpx) and sqlite3 on the store."""

from __future__ import annotations

import sqlite3
from datetime import datetime, timedelta, timezone
from pathlib import Path

from service_test_support import AUTH, api_client, running_service, to_execute


def _window(since: datetime, until: datetime) -> dict[str, str]:
    return {"since": since.isoformat(), "until": until.isoformat()}


async def test_a_window_ahead_of_the_cells_clock_ends_at_its_clock_and_the_next_one_lists_the_install(tmp_path: Path) -> None:
    async with running_service(tmp_path) as service, api_client(service) as client:
        await to_execute(client)
        start = datetime.now(timezone.utc) - timedelta(minutes=1)
        ahead = datetime.now(timezone.utc) + timedelta(minutes=10)  # the MES host's clock, 10 min ahead
        before = datetime.now(timezone.utc)
        first = (await client.get("/parts", params=_window(start, ahead))).json()
        applied = datetime.fromisoformat(first["until"])
        assert before <= applied <= datetime.now(timezone.utc), (before, applied)
        r = await client.post("/cycle?wait=true&timeout_s=120", json={"recipe": "side-window", "part_id": "MES-1"},
                              headers={**AUTH, "Idempotency-Key": "mes-1"})  # fmt: skip
        assert r.status_code == 200 and r.json()["state"] == "done", r.text
        cycle_id = r.json()["id"]
        second = (await client.get("/parts", params=_window(applied, ahead + timedelta(minutes=1)))).json()
    listed = [[i["cycle_id"] for i in page["installs"]] for page in (first, second)]
    assert listed == [[], [cycle_id]], listed  # in exactly one of the two back-to-back windows
    with sqlite3.connect(tmp_path / "var" / "cellctl.db") as db:
        (finished,) = db.execute("SELECT finished_at FROM cycles WHERE id = ?", (cycle_id,)).fetchone()
    assert applied <= datetime.fromisoformat(finished) < ahead  # it ended inside the first window as the MES asked it


async def test_a_window_in_the_past_is_applied_as_given(tmp_path: Path) -> None:
    async with running_service(tmp_path) as service, api_client(service) as client:
        until = datetime(2026, 1, 1, 12, tzinfo=timezone.utc)
        page = (await client.get("/parts", params=_window(until - timedelta(hours=8), until))).json()
        assert datetime.fromisoformat(page["until"]) == until and page["installs"] == []
        assert (await client.get("/parts")).json()["until"] is None  # no window: no bound
