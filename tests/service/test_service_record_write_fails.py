"""A finished cycle whose final record the store refuses (disk full, a lock held) is not lost: alarm 1703 names
the fault and the cycle, the cell leaves Execute and takes no next cycle, and the record holds the final result
once the store takes writes again (read back over REST and with a second SQLite connection)."""

from __future__ import annotations

import asyncio
import json
import logging
import sqlite3
from pathlib import Path
from typing import Any

import httpx
import pytest
from shared_support import eventually
from service_test_support import AUTH, api_client, back_to_execute, running_service, sim_config, to_execute

from cellctl.domain import CycleStep

pytestmark = pytest.mark.timeout(180)

RECORD_WRITE_FAILED = 1703  # docs/alarm_reactions.md


async def _active_alarm(client: httpx.AsyncClient, code: int) -> dict[str, Any] | None:
    alarms = (await client.get("/alarms")).json()["current"]
    return next((a for a in alarms if a["code"] == code and a["active"]), None)


async def _settled(client: httpx.AsyncClient) -> dict[str, Any] | None:
    st = (await client.get("/status")).json()
    return None if st["state"].endswith("ING") or st["current_cycle"] is not None else st


def _kept_json(caplog: pytest.LogCaptureFixture, cycle_id: int) -> dict[str, Any]:
    """The cycle's outcome as logged (one JSON line) when the store refused it."""
    lines = [r.getMessage() for r in caplog.records if "kept in memory until the store takes it" in r.getMessage()]
    assert len(lines) == 1, lines
    kept = json.loads(lines[0].split("takes it: ", 1)[1])
    assert kept["cycle_id"] == cycle_id and kept["state"] == "done"
    return kept


async def test_a_refused_final_record_holds_the_cell_and_is_written_when_the_store_recovers(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="cellctl.cell.final_record")
    cfg = sim_config(plc={"enabled": False})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        await to_execute(client)
        sync = service.store._store  # the store boundary: the synchronous store the async one runs on its thread

        def disk_full(*args: object, **kwargs: object) -> None:
            raise sqlite3.OperationalError("database or disk is full")

        sync.complete_cycle = disk_full
        r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "P-DISK"},
                              headers={**AUTH, "Idempotency-Key": "disk-1"})  # fmt: skip
        assert r.status_code == 202, r.text
        cid = r.json()["cycle_id"]

        alarm = await eventually("alarm 1703", lambda: _active_alarm(client, RECORD_WRITE_FAILED), 90.0)
        assert alarm["cycle_id"] == cid and f"cycle {cid}" in alarm["message"], alarm
        assert "database or disk is full" in alarm["message"], alarm
        st = await eventually("the cell to settle", lambda: _settled(client), 90.0)
        assert st["state"] == "HELD", st
        assert st["stop_reason"]["code"] == RECORD_WRITE_FAILED, st
        rec = (await client.get(f"/cycles/{cid}")).json()
        assert rec["state"] == "running" and rec["install_started_at"], rec  # not written yet; never installed again

        r2 = await client.post("/cycle", json={"recipe": "side-window", "part_id": "P-NEXT"},
                               headers={**AUTH, "Idempotency-Key": "disk-2"})  # fmt: skip
        assert r2.status_code == 409, r2.text  # no install without a record
        assert (await client.post("/commands/unhold", headers=AUTH)).status_code == 409
        await asyncio.sleep(3.5)  # a retry (every 3 s), refused as well
        assert await _active_alarm(client, RECORD_WRITE_FAILED) is not None
        kept = _kept_json(caplog, cid)

        del sync.complete_cycle  # the store takes writes again
        await eventually("alarm 1703 to clear once the record is written", lambda: _cleared(client), 10.0)
        rec = (await client.get(f"/cycles/{cid}")).json()
        assert rec["state"] == "done", rec
        assert rec["result"]["measured_deviation"] == kept["result"]["measured_deviation"], (rec, kept)
        db = sqlite3.connect((await service.store.info()).path)  # a second connection: what the store holds
        try:
            state, result_json = db.execute("SELECT state, result_json FROM cycles WHERE id = ?", (cid,)).fetchone()
        finally:
            db.close()
        assert state == "done" and json.loads(result_json)["ok"] == kept["result"]["ok"]

        await back_to_execute(client)  # the operator's Unhold, now allowed
        r3 = await client.post("/cycle?wait=true&timeout_s=90", json={"recipe": "side-window", "part_id": "P-NEXT"},
                               headers={**AUTH, "Idempotency-Key": "disk-3"})  # fmt: skip
        assert r3.status_code == 200 and r3.json()["state"] == "done", r3.text


async def _cleared(client: httpx.AsyncClient) -> bool:
    alarms = (await client.get("/alarms")).json()["current"]
    return any(a["code"] == RECORD_WRITE_FAILED and not a["active"] for a in alarms)


async def test_a_database_locked_by_another_process_after_the_install_loses_no_outcome(tmp_path: Path) -> None:
    """The real fault: another connection holds the write lock from the inspection on, so every write fails."""
    cfg = sim_config(plc={"enabled": False}, store={"busy_timeout_s": 0.2})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        await to_execute(client)
        holder = sqlite3.connect((await service.store.info()).path, isolation_level=None, check_same_thread=False)
        sync = service.store._store
        begin_step = sync.begin_step

        def lock_after_install(cycle_id: int, step: CycleStep, *args: object, **kwargs: object) -> object:
            began = begin_step(cycle_id, step, *args, **kwargs)
            if CycleStep(step) is CycleStep.INSPECT:  # the install marker is written: the glass is in
                holder.execute("BEGIN EXCLUSIVE")
            return began

        sync.begin_step = lock_after_install
        try:
            r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "P-LOCK"},
                                  headers={**AUTH, "Idempotency-Key": "lock-1"})  # fmt: skip
            cid = r.json()["cycle_id"]
            alarm = await eventually("alarm 1703", lambda: _active_alarm(client, RECORD_WRITE_FAILED), 90.0)
            assert alarm["cycle_id"] == cid and "database is locked" in alarm["message"], alarm
            st = await eventually("the cell to settle", lambda: _settled(client), 90.0)
            assert st["state"] not in ("EXECUTE", "IDLE"), st
            assert (await client.get(f"/cycles/{cid}")).json()["state"] == "running"
        finally:
            del sync.begin_step
            if holder.in_transaction:
                holder.execute("ROLLBACK")
            holder.close()
        await eventually("alarm 1703 to clear once the record is written", lambda: _cleared(client), 10.0)
        rec = (await client.get(f"/cycles/{cid}")).json()
        assert rec["state"] in ("done", "failed") and rec["install_started_at"], rec
        st = (await client.get("/status")).json()
        assert st["state"] not in ("EXECUTE", "IDLE") and not st["state"].endswith("ING"), st
