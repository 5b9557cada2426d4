"""Another process holds the store's write lock while the operator commands the cell and acknowledges alarms.

What took effect is never lost: the Hold, its state completion and the acknowledgement reach the audit log (read with a
second SQLite connection) once the store takes writes again, in order, at the time they happened; the acknowledgement
answers 200 (it took effect), not 500; the alarm history has alarm 1703 with its acknowledgement. Meanwhile /health
answers within about a second, 503 with why (over HTTP, with httpx)."""

from __future__ import annotations

import asyncio
import sqlite3
import time
from datetime import datetime, timezone
from pathlib import Path

import httpx
import pytest
from shared_support import eventually, read_store
from service_test_support import AUTH, api_client, running_service, served, sim_config, to_execute

pytestmark = pytest.mark.timeout(120)

RECORD_WRITE_FAILED = 1703


async def test_commands_and_acknowledgements_during_a_lock_reach_the_audit_log_and_health_answers_at_once(
    tmp_path: Path,
) -> None:
    cfg = sim_config(plc={"enabled": False}, store={"busy_timeout_s": 3.0})
    async with running_service(tmp_path, cfg) as service, api_client(service) as setup:
        await to_execute(setup)
        db_path = (await service.store.info()).path
        (last_seq,), = read_store(db_path, "SELECT COALESCE(MAX(seq), 0) FROM audit_log")
        holder = sqlite3.connect(db_path, isolation_level=None)
        async with served(service) as url, httpx.AsyncClient(base_url=url, timeout=30) as client:
            holder.execute("BEGIN EXCLUSIVE")  # a backup, an engineer's query
            try:
                r = await client.post("/commands/hold", headers=AUTH)
                assert r.status_code == 200 and r.json()["state"] in ("HOLDING", "HELD"), r.text
                await asyncio.sleep(0.1)  # the Hold's audit entry now waits for the lock
                t0 = time.monotonic()
                h = await client.get("/health", headers=AUTH)
                took = time.monotonic() - t0
                assert took < 2.0, f"/health took {took:.1f} s while the store was locked"
                assert h.status_code == 503 and any("store" in p for p in h.json()["problems"]), h.text

                await eventually("alarm 1703 (the audit entry kept)", lambda: _active(client), 30.0)
                h = await client.get("/health", headers=AUTH)
                assert h.status_code == 503 and any("1703" in p for p in h.json()["problems"]), h.text
                ack = await client.post("/alarms/acknowledge-all", headers=AUTH)
                assert ack.status_code == 200, ack.text  # it took effect
                assert any(a["code"] == RECORD_WRITE_FAILED and a["acknowledged"] for a in ack.json()), ack.text
                assert (await client.get("/status")).json()["state"] == "HELD"
            finally:
                released_at = datetime.now(timezone.utc)
                holder.execute("ROLLBACK")  # the other process lets go
                holder.close()
            await eventually("alarm 1703 to clear once everything kept is written", lambda: _cleared(client), 30.0)
            assert (await client.get("/health", headers=AUTH)).status_code == 200

    rows = read_store(db_path, "SELECT seq, at, action, state_before, state_after FROM audit_log WHERE seq > ? ORDER BY seq", last_seq)
    actions = [r[2] for r in rows]
    assert "command:hold" in actions and "alarm.acknowledge_all" in actions, rows
    hold = rows[actions.index("command:hold")]
    assert (hold[3], hold[4]) == ("EXECUTE", "HOLDING"), hold
    ack_at = rows[actions.index("alarm.acknowledge_all")][1]
    assert datetime.fromisoformat(ack_at) < released_at, (ack_at, released_at)  # stamped when it happened, not when written
    states = [r for r in rows if r[4] is not None]
    assert [(a[4], b[3]) for a, b in zip(states, states[1:]) if a[4] != b[3]] == [], states  # no state change missing
    assert any(r[2] == "state_complete" and (r[3], r[4]) == ("HOLDING", "HELD") for r in rows), rows
    assert actions.index("command:hold") < actions.index("alarm.acknowledge_all"), actions  # in the order they happened
    acked = read_store(db_path, "SELECT ack_by FROM alarms WHERE code = ?", RECORD_WRITE_FAILED)
    assert acked and all(by is not None for (by,) in acked), acked  # the acknowledgement is in the alarm history


async def _active(client: httpx.AsyncClient) -> bool:
    return any(a["code"] == RECORD_WRITE_FAILED and a["active"] for a in (await client.get("/alarms")).json()["current"])


async def _cleared(client: httpx.AsyncClient) -> bool:
    return not await _active(client)
