"""A failed cycle on a real broker (mosquitto, a paho subscriber): its result carries no correction it never computed,
and its latched alarm, cleared by the operator's acknowledgement, is on ``alarm/events`` as cleared and acknowledged."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from mqtt_service_support import broker_and_historian, run_cycle
from service_test_support import AUTH, api_client, running_service, to_execute

from cellctl.domain import AlarmCode


async def _failed_cycle(client: Any, service: Any) -> dict[str, Any]:
    """A cycle with the laser silent: it fails in align, before it computes a correction or measures; its REST record."""
    laser = service.extras["fakes"]["laser"]
    laser.silence(count=None)
    try:
        r = await client.post("/cycle?wait=true&timeout_s=90", json={"recipe": "side-window", "part_id": "G-FAIL", "car_id": "CB-9"},
                              headers={**AUTH, "Idempotency-Key": "mqtt-failed"})  # fmt: skip
    finally:
        laser.speak()
    assert r.status_code == 200, r.text
    record = dict(r.json())
    assert record["state"] == "failed", record
    return record


async def _alarm_history(client: Any, cycle_id: int) -> list[dict[str, Any]]:
    """The REST history of the cycle's laser alarm, once the store holds it acknowledged (at most 100 reads)."""
    for _ in range(100):
        history = (await client.get("/alarms?history=true", headers=AUTH)).json().get("history") or []
        mine = [a for a in history if a["cycle_id"] == cycle_id and a["code"] == int(AlarmCode.LASER_READ_FAILED)]
        if mine and all(a["acknowledged"] for a in mine):
            return mine
        await asyncio.sleep(0.1)
    raise AssertionError(f"no acknowledged alarm {int(AlarmCode.LASER_READ_FAILED)} of cycle {cycle_id} in GET /alarms?history=true")


async def test_a_failed_cycle_publishes_null_corrections_and_its_alarm_cleared_then_acknowledged(tmp_path: Path) -> None:
    with broker_and_historian(tmp_path) as (broker, config, t, sub):
        async with running_service(tmp_path, config) as service, api_client(service) as client:
            await to_execute(client)
            done = await run_cycle(client, 1)
            assert done["state"] == "done", done
            failed = await _failed_cycle(client, service)
            part = (await client.get("/parts/G-FAIL", headers=AUTH)).json()
            await asyncio.to_thread(sub.wait_count, t.result, 2)
            r = await client.post("/alarms/acknowledge-all", headers=AUTH)
            assert r.status_code == 200, r.text
            await asyncio.to_thread(sub.wait_for, "the failed cycle's alarm acknowledged", lambda: any(
                m.json()["cycle_id"] == failed["id"] and m.json()["event"] == "acknowledged" for m in sub.on(t.alarm_events)))
            history = await _alarm_history(client, failed["id"])
        results = {m.json()["cycle_id"]: m.json() for m in sub.on(t.result)}
        lasts = {m.json()["cycle_id"]: m.json() for m in sub.on(t.result_last)}

        # The record (REST) of the failed cycle has no correction: the parts document says null, and so must MQTT.
        assert "correction_mm" not in (failed["result"] or {}) and failed["measured_deviation"] is None
        assert part["installs"][0]["correction_mm"] is None and part["installs"][0]["correction_deg"] is None
        for body in (results[failed["id"]], lasts[failed["id"]]):
            assert (body["correction_mm"], body["correction_deg"]) == (None, None), body
            assert body["ok"] is False and body["state"] == "failed" and body["measured_deviation"] is None
        # A done cycle's correction is the one its record computed (a zero would still be published as one).
        ok = results[done["id"]]
        assert ok["correction_mm"] == done["result"]["correction_mm"] and ok["correction_deg"] == done["result"]["correction_deg"]

        # The cycle's latched alarm: raised, then cleared and acknowledged by the one acknowledgement.
        assert len(history) == 1 and history[0]["cleared_at"] is not None and history[0]["ack_at"] is not None, history
        uid = history[0]["uid"]
        events = [m.json() for m in sub.on(t.alarm_events) if m.json()["uid"] == uid]
        assert [e["event"] for e in events] == ["raised", "cleared", "acknowledged"], events
        assert [(e["active"], e["acknowledged"]) for e in events] == [(True, False), (False, True), (False, True)]
        assert events[1]["seq"] < events[2]["seq"] and events[1]["msg_id"] != events[2]["msg_id"]
        assert events[1]["cleared_at"] is not None and events[2]["acknowledged_by"] == "operator"

