"""Another process holds the store's write lock (a backup, an engineer's sqlite3 shell) while a cycle runs.

After the install began, the glass is in: the cycle goes on, measures it and ends ``done`` with its measurement once the
store takes writes again, its steps closed (read with a second SQLite connection; the twin's true error says the glass
is good). Before the install the cycle ends as a store fault (error code 1703, alarm 1703 in the history), never as a
software fault (1501), and no step is left open."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager, contextmanager
from pathlib import Path
from typing import Any

import httpx
import pytest
from shared_support import eventually, read_store
from service_test_support import AUTH, api_client, back_to_execute, running_service, sim_config, to_execute

from cellctl.domain import CycleStep

pytestmark = pytest.mark.timeout(120)

RECORD_WRITE_FAILED, TASK_FAILED = 1703, 1501  # docs/alarm_reactions.md


async def _alarm_active(client: httpx.AsyncClient, code: int) -> bool:
    return any(a["code"] == code and a["active"] for a in (await client.get("/alarms")).json()["current"])


@contextmanager
def _lock_from(service: Any, db_path: Path, step: CycleStep) -> Iterator[sqlite3.Connection]:
    """A second SQLite connection that takes BEGIN EXCLUSIVE as soon as the cycle's ``step`` row is written (the
    store's ``begin_step`` only tells when); the test ends the transaction to free the store."""
    holder = sqlite3.connect(db_path, isolation_level=None, check_same_thread=False)
    sync = service.store._store
    begin_step = sync.begin_step

    def then_lock(cycle_id: int, s: CycleStep, *args: object, **kwargs: object) -> object:
        began = begin_step(cycle_id, s, *args, **kwargs)
        if CycleStep(s) is step and not holder.in_transaction:
            holder.execute("BEGIN EXCLUSIVE")
        return began

    sync.begin_step = then_lock
    try:
        yield holder
    finally:
        del sync.begin_step
        if holder.in_transaction:
            holder.execute("ROLLBACK")
        holder.close()


@asynccontextmanager
async def _cycle_under_lock(service: Any, client: httpx.AsyncClient, step: CycleStep,
                            key: str) -> AsyncIterator[tuple[sqlite3.Connection, Path, int]]:
    """The cell in Execute, the store locked from the cycle's ``step`` on (:func:`_lock_from`), and that cycle asked
    for: (the lock's holder, the store file, the cycle's id)."""
    await to_execute(client)
    db_path = (await service.store.info()).path
    with _lock_from(service, db_path, step) as holder:
        r = await client.post("/cycle", json={"recipe": "side-window", "part_id": f"P-{key}"},
                              headers={**AUTH, "Idempotency-Key": key})  # fmt: skip
        yield holder, db_path, r.json()["cycle_id"]


def _open_steps(db_path: Path, cid: int) -> list[tuple[Any, ...]]:
    return read_store(db_path, "SELECT step, attempt FROM cycle_steps WHERE cycle_id = ? AND finished_at IS NULL", cid)


async def test_a_lock_during_the_inspection_keeps_the_installed_glass_done_with_its_measurement(tmp_path: Path) -> None:
    cfg = sim_config(plc={"enabled": False}, store={"busy_timeout_s": 0.3})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        async with _cycle_under_lock(service, client, CycleStep.INSPECT, "lock-inspect") as (holder, db_path, cid):
            await eventually("alarm 1703 (the cycle's end is kept)", lambda: _alarm_active(client, RECORD_WRITE_FAILED), 30.0)
            assert (await client.get("/status")).json()["current_cycle"] is None
            assert holder.in_transaction
            holder.execute("COMMIT")  # the other process lets go
        await eventually("alarm 1703 to clear once everything kept is written", lambda: _cleared(client), 30.0)

        (state, error, install, result, true_error), = read_store(
            db_path, "SELECT state, error, install_started_at, result_json, true_error_json FROM cycles WHERE id = ?", cid)
        truth = json.loads(true_error)
        assert all(abs(truth[k]) < 0.5 for k in ("dx_mm", "dy_mm", "dz_mm")), truth  # the twin: a good glass
        assert state == "done" and error is None and install is not None, (state, error)
        assert json.loads(result)["measured_deviation"] is not None, result
        assert _open_steps(db_path, cid) == []  # the inspect step is closed too
        assert read_store(db_path, "SELECT name FROM cycle_images WHERE cycle_id = ? AND name = 'inspect'", cid)
        codes = {c for (c,) in read_store(db_path, "SELECT code FROM alarms")}
        assert TASK_FAILED not in codes and RECORD_WRITE_FAILED in codes, codes

        await back_to_execute(client)  # no restart: the cell takes the next cycle
        r = await client.post("/cycle?wait=true&timeout_s=60", json={"recipe": "side-window", "part_id": "P-NEXT"},
                              headers={**AUTH, "Idempotency-Key": "lock-inspect-next"})  # fmt: skip
        assert r.status_code == 200 and r.json()["state"] == "done", r.text


async def test_a_lock_before_the_install_fails_the_cycle_as_a_store_fault_not_a_software_fault(tmp_path: Path) -> None:
    cfg = sim_config(plc={"enabled": False}, store={"busy_timeout_s": 0.3})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        async with _cycle_under_lock(service, client, CycleStep.ALIGN, "lock-align") as (holder, db_path, cid):
            await eventually("alarm 1703", lambda: _alarm_active(client, RECORD_WRITE_FAILED), 30.0)
            st = await eventually("the cycle to end", lambda: _settled(client), 30.0)
            assert st["state"] == "HELD" and st["stop_reason"]["code"] == RECORD_WRITE_FAILED, st
            holder.execute("COMMIT")
        await eventually("alarm 1703 to clear once everything kept is written", lambda: _cleared(client), 30.0)

        (state, error, install, result), = read_store(
            db_path, "SELECT state, error, install_started_at, result_json FROM cycles WHERE id = ?", cid)
        assert state == "failed" and install is None, (state, install)
        assert json.loads(result)["error_code"] == RECORD_WRITE_FAILED, (error, result)
        assert "software fault" not in error and ("1703" in error or "store" in error), error
        assert _open_steps(db_path, cid) == []
        codes = {c for (c,) in read_store(db_path, "SELECT code FROM alarms")}
        assert TASK_FAILED not in codes and RECORD_WRITE_FAILED in codes, codes  # the code the record gives is in the history


async def _settled(client: httpx.AsyncClient) -> dict[str, Any] | None:
    st = (await client.get("/status")).json()
    return None if st["state"].endswith("ING") or st["current_cycle"] is not None else st


async def _cleared(client: httpx.AsyncClient) -> bool:
    alarms = (await client.get("/alarms")).json()["current"]
    return any(a["code"] == RECORD_WRITE_FAILED for a in alarms) and not await _alarm_active(client, RECORD_WRITE_FAILED)
