"""How a cycle ends when the cell is told to end production: Complete waits for it, a Stop or Abort ends the
cycles queued behind it, and a service stop waits for a finished cycle's record."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
from service_test_support import AUTH, _command, api_client, running_service, sim_config, slow_moves, to_execute

from cellctl.service import build_service

from cellctl.store import CellStore

pytestmark = pytest.mark.timeout(180)


async def _submit(client: Any, key: str) -> int:
    r = await client.post("/cycle", json={"recipe": "side-window", "part_id": f"P-{key}"}, headers={**AUTH, "Idempotency-Key": key})
    assert r.status_code == 202, r.text
    return int(r.json()["cycle_id"])


async def _until(what: str, check: Any, timeout_s: float = 60.0) -> None:
    for _ in range(int(timeout_s / 0.01)):
        if await check():
            return
        await asyncio.sleep(0.01)
    raise AssertionError(f"not within {timeout_s} s: {what}")


async def _one_running_one_queued(service: Any, client: Any) -> tuple[int, int]:
    """In Execute with slow moves: cycle A running, cycle B queued behind it; their ids."""
    await to_execute(client)
    slow_moves(service, 30.0)
    a, b = await _submit(client, "A"), await _submit(client, "B")

    async def a_runs() -> bool:
        return (await service.store.cycle(a)).state.value == "running"

    await _until("cycle A runs", a_runs)
    return a, b


async def test_complete_is_held_back_while_a_cycle_moves_the_robot_and_taken_once_it_has_ended(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        await to_execute(client)
        slow_moves(service, 30.0)
        cid = await _submit(client, "complete")
        robot = service.orchestrator.robot

        async def moving() -> bool:
            return bool(robot.moving)

        await _until("the robot moves", moving)
        r = await client.post("/commands/complete", headers=AUTH)
        assert r.status_code == 409, r.text
        assert f"cycle {cid} is running" in r.text and "Stop or Hold" in r.text
        status = (await client.get("/status")).json()
        assert status["state"] == "EXECUTE" and "complete" in status["blocked_commands"]
        slow_moves(service, 1.0 / 30.0)

        async def ended() -> bool:  # what the operator sees: no cycle running any more
            return (await client.get("/status")).json()["current_cycle"] is None

        await _until("the cycle ends", ended, timeout_s=120)
        assert (await _command(client, "complete")) == "COMPLETE"
        assert not robot.moving
        rec = (await client.get(f"/cycles/{cid}")).json()
        assert rec["state"] == "done", rec


async def test_an_abort_ends_the_cycles_queued_behind_the_running_one_with_the_reason(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        a, b = await _one_running_one_queued(service, client)
        assert (await client.get("/status")).json()["queued_cycles"] == 1
        assert await _command(client, "abort") == "ABORTED"
        rec_b = await service.store.cycle(b)
        assert rec_b.state.value == "failed" and rec_b.started_at is None
        assert rec_b.error is not None and "not started" in rec_b.error and "aborting" in rec_b.error
        assert "in Execute, request it again with a new request id" in rec_b.error, rec_b.error
        assert (await client.get("/status")).json()["queued_cycles"] == 0
        slow_moves(service, 1.0 / 30.0)
        for cmd in ("clear", "reset", "start"):
            await _command(client, cmd)
        await asyncio.sleep(1.0)
        assert (await service.store.cycle(b)).started_at is None  # never started by itself later


async def test_a_hold_keeps_the_queued_cycles_for_the_unhold(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        a, b = await _one_running_one_queued(service, client)
        assert await _command(client, "hold") == "HELD"
        assert (await service.store.cycle(b)).state.value == "queued"
        slow_moves(service, 1.0 / 30.0)
        assert await _command(client, "unhold") == "EXECUTE"

        async def b_done() -> bool:
            return (await service.store.cycle(b)).state.value == "done"

        await _until("the queued cycle runs after the unhold", b_done, timeout_s=120)


async def test_a_service_stop_while_a_finished_cycle_records_keeps_its_result(tmp_path: Path) -> None:
    cfg = sim_config(plc={"enabled": False})
    service = await build_service(cfg, workdir=tmp_path)
    await service.start()
    orch = service.orchestrator
    recording = asyncio.Event()
    after_cycle = orch.quality.after_cycle

    async def slow_after_cycle(*args: Any, **kwargs: Any) -> Any:  # the closed loop's update, between two store calls
        recording.set()
        await asyncio.sleep(0.5)
        return await after_cycle(*args, **kwargs)

    orch.quality.after_cycle = slow_after_cycle  # type: ignore[method-assign]
    try:
        async with api_client(service) as client:
            await to_execute(client)
            cid = await _submit(client, "record")
            await asyncio.wait_for(recording.wait(), 150)  # installed and inspected: its record is being written
    finally:
        await service.stop()  # what SIGTERM does
    with CellStore.open(tmp_path / cfg.store.path) as store:
        rec = store.cycle(cid)
    assert rec.state.value == "done", f"cycle {cid} is {rec.state.value} after a clean stop"
    assert rec.result is not None and "spc" in rec.result


async def test_a_cycle_stopped_before_its_first_step_waits_for_the_unhold_or_ends_with_the_abort(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        orch = service.orchestrator
        await to_execute(client)
        entered = asyncio.Event()

        async def not_begun(cycle_id: int) -> None:  # the cycle's task runs, its cycle has not begun
            entered.set()
            await asyncio.Event().wait()

        orch._run = not_begun  # type: ignore[method-assign]
        cid = await _submit(client, "early")
        await asyncio.wait_for(entered.wait(), 10)
        assert await _command(client, "hold") == "HELD"
        assert (await service.store.cycle(cid)).state.value == "queued"
        assert (await client.get("/status")).json()["queued_cycles"] == 1
        del orch._run  # type: ignore[attr-defined]
        assert await _command(client, "unhold") == "EXECUTE"

        async def done() -> bool:
            return (await service.store.cycle(cid)).state.value == "done"

        await _until("the held cycle runs after the unhold", done, timeout_s=120)
        entered.clear()
        orch._run = not_begun  # type: ignore[method-assign]
        other = await _submit(client, "early-2")
        await asyncio.wait_for(entered.wait(), 10)
        assert await _command(client, "abort") == "ABORTED"
        rec = await service.store.cycle(other)
        assert rec.state.value == "failed" and rec.error is not None and rec.error.startswith("not started")


async def test_complete_waits_for_the_queued_cycles_too_and_each_of_them_runs(tmp_path: Path) -> None:
    """The MES queues two installs, then asks for Complete until it is taken: never while one still waits its turn
    (it would wait in the queue of a Complete cell, then start by itself after the next Reset and Start)."""
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        a, b = await _one_running_one_queued(service, client)
        r = await client.post("/commands/complete", headers=AUTH)
        assert r.status_code == 409 and f"cycle {a} is running and queued cycles {b}:" in r.json()["detail"], r.text
        slow_moves(service, 1.0 / 30.0)
        refusals: list[str] = []
        while (r := await client.post("/commands/complete", headers=AUTH)).status_code != 200:
            assert r.status_code == 409, r.text
            refusals.append(r.json()["detail"])
            await asyncio.sleep(0.002)
        await _until("the cell is Complete", lambda: _in_state(client, "COMPLETE"))
        recs = [(await client.get(f"/cycles/{c}")).json() for c in (a, b)]
        assert [r["state"] for r in recs] == ["done", "done"], recs
        assert (await client.get("/status")).json()["queued_cycles"] == 0


async def test_a_request_stored_as_a_stop_comes_is_dropped_at_once_not_left_queued(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        orch = service.orchestrator
        await to_execute(client)
        submit = orch.store.submit_cycle

        async def stop_meanwhile(*args: Any, **kwargs: Any) -> Any:  # the Stop lands while the request is stored
            stopping = asyncio.create_task(client.post("/commands/stop", headers=AUTH))
            await _until("the cell leaves Execute", lambda: _left_execute(client))
            result = await submit(*args, **kwargs)
            await stopping
            return result

        orch.store.submit_cycle = stop_meanwhile  # type: ignore[method-assign]
        cid = await _submit(client, "late")
        orch.store.submit_cycle = submit  # type: ignore[method-assign]
        rec = (await client.get(f"/cycles/{cid}")).json()
        assert rec["state"] == "failed" and "not started" in rec["error"], rec
        assert (await client.get("/status")).json()["queued_cycles"] == 0
        for cmd in ("reset", "start"):
            await _command(client, cmd)
        await asyncio.sleep(1.0)
        assert (await client.get(f"/cycles/{cid}")).json()["started_at"] is None  # never started by itself later


async def _left_execute(client: Any) -> bool:
    return (await client.get("/status")).json()["state"] != "EXECUTE"


async def _in_state(client: Any, state: str) -> bool:
    return bool((await client.get("/status")).json()["state"] == state)
