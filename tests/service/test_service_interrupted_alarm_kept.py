"""Alarm 1306 (a cycle cut off by a restart: check the glass by hand) is stored when it is raised, and a latched alarm
nobody acknowledged is listed again after the next restart, until someone does. The peers: sqlite3 on the store and
the REST API (httpx) of the served cell."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from service_test_support import AUTH, api_client, running_service

from cellctl.store.db import CellStore
from cellctl.store.records import CycleRequest


def _rows_1306(db: Path) -> list[tuple[str, int, str | None, str | None]]:
    with sqlite3.connect(db) as c:
        return c.execute("SELECT uid, cycle_id, ack_at, ack_by FROM alarms WHERE code = 1306").fetchall()


def _cut_off_cycle(db: Path) -> int:
    """A cycle left running, as a process killed mid-cycle leaves it."""
    store = CellStore.open(db)
    try:
        sub = store.submit_cycle(CycleRequest(recipe="side-window", part_id="G/4711"), scope="test", key="cut-1", actor="t")
        return store.start_cycle(sub.cycle.id).id
    finally:
        store.close()


async def test_an_interrupted_cycles_alarm_is_stored_at_once_and_listed_after_another_restart(tmp_path: Path) -> None:
    db = tmp_path / "var" / "cellctl.db"
    async with running_service(tmp_path):
        pass  # the store is made
    cycle_id = _cut_off_cycle(db)
    async with running_service(tmp_path) as service, api_client(service) as client:
        current = [a for a in (await client.get("/alarms")).json()["current"] if a["code"] == 1306]
        assert [a["cycle_id"] for a in current] == [cycle_id], current
        rows = _rows_1306(db)
        assert [(uid, cid, ack) for uid, cid, ack, _ in rows] == [(current[0]["uid"], cycle_id, None)], rows
    async with running_service(tmp_path) as service, api_client(service) as client:  # nobody acknowledged it
        current = [a for a in (await client.get("/alarms")).json()["current"] if a["code"] == 1306]
        assert [(a["uid"], a["cycle_id"], a["acknowledged"]) for a in current] == [(rows[0][0], cycle_id, False)], current
        r = await client.post(f"/alarms/{rows[0][0]}/acknowledge", headers=AUTH)
        assert r.status_code == 200, r.text
        assert not [a for a in (await client.get("/alarms")).json()["current"] if a["code"] == 1306]
    (uid, cid, ack_at, ack_by), = _rows_1306(db)
    assert (uid, cid) == (rows[0][0], cycle_id) and ack_at is not None and ack_by, (ack_at, ack_by)
    async with running_service(tmp_path) as service, api_client(service) as client:  # acknowledged: not listed again
        assert not [a for a in (await client.get("/alarms")).json()["current"] if a["code"] == 1306]
