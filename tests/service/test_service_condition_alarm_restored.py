"""A condition alarm nobody acknowledged before a restart (cleared, or still present as the service stopped) is listed
again after it, inactive, until someone acknowledges it; the store then says so. The peers: sqlite3 on the store and
the REST API (httpx) of the served cell."""

from __future__ import annotations

import sqlite3
from datetime import datetime, timedelta, timezone
from pathlib import Path

from service_test_support import AUTH, api_client, running_service

from cellctl.cell.alarm_table import ALARM_CATALOGUE, REACTIONS
from cellctl.domain import Alarm, AlarmCode
from cellctl.store.db import CellStore

RAISED = datetime(2026, 11, 30, 3, 0, tzinfo=timezone.utc)


def _condition_alarm(uid: str, code: AlarmCode, source: str, *, cleared: bool) -> Alarm:
    spec = ALARM_CATALOGUE[code]
    assert spec.condition
    return Alarm(uid=uid, code=code, value=0, message=spec.text, category=spec.fault_class,
                 severity=REACTIONS[spec.fault_class].severity, source=source, raised_at=RAISED, active=not cleared,
                 condition=True, cleared_at=RAISED + timedelta(seconds=40) if cleared else None)


def _rows(db: Path) -> dict[str, tuple[int, str | None]]:
    with sqlite3.connect(db) as c:
        return {uid: (active, ack) for uid, active, ack in c.execute("SELECT uid, active, ack_at FROM alarms WHERE uid LIKE 'prev-%'")}


async def test_an_unacknowledged_condition_alarm_is_listed_after_a_restart_until_acknowledged(tmp_path: Path) -> None:
    db = tmp_path / "var" / "cellctl.db"
    async with running_service(tmp_path):
        pass  # the store is made
    store = CellStore.open(db)  # what the previous run left: one came and went at night, one was present as it stopped
    try:
        store.save_alarm(_condition_alarm("prev-cleared", AlarmCode.LASER_LOST, "laser", cleared=True))
        store.save_alarm(_condition_alarm("prev-present", AlarmCode.CAMERA_LOST, "camera", cleared=False))
    finally:
        store.close()
    async with running_service(tmp_path) as service, api_client(service) as client:
        listed = {a["uid"]: a for a in (await client.get("/alarms")).json()["current"] if a["uid"].startswith("prev-")}
        assert sorted(listed) == ["prev-cleared", "prev-present"], listed
        assert not any(a["active"] or a["acknowledged"] for a in listed.values()), listed
        assert _rows(db) == {"prev-cleared": (0, None), "prev-present": (0, None)}  # no longer "active" in the store
        for uid in listed:
            r = await client.post(f"/alarms/{uid}/acknowledge", headers=AUTH)
            assert r.status_code == 200, r.text
        assert not [a for a in (await client.get("/alarms")).json()["current"] if a["uid"].startswith("prev-")]
    assert all(active == 0 and ack is not None for active, ack in _rows(db).values()), _rows(db)
    async with running_service(tmp_path) as service, api_client(service) as client:  # acknowledged: not listed again
        assert not [a for a in (await client.get("/alarms")).json()["current"] if a["uid"].startswith("prev-")]


async def test_acknowledgements_made_as_the_service_stops_are_all_stored(tmp_path: Path) -> None:
    """The stop hands every alarm event queued so far to the store before it closes: the operator's acknowledge-all
    answered 200 just before a SIGTERM is in the store (it was lost when the record's write was still queued)."""
    db = tmp_path / "var" / "cellctl.db"
    async with running_service(tmp_path):
        pass
    store = CellStore.open(db)
    try:
        for i in range(40):
            store.save_alarm(_condition_alarm(f"prev-{i:02d}", AlarmCode.LASER_LOST, f"laser{i}", cleared=True))
    finally:
        store.close()
    async with running_service(tmp_path) as service, api_client(service) as client:
        r = await client.post("/alarms/acknowledge-all", headers=AUTH)
        assert r.status_code == 200, r.text
        assert sum(a["uid"].startswith("prev-") for a in r.json()) == 40
    rows = _rows(db)
    assert len(rows) == 40 and [uid for uid, (_, ack) in rows.items() if ack is None] == [], rows
