"""A PackML Stop while a commissioning job runs in Stopped (where `cellctl command clear` leaves the cell): the
state table has no Stop there, yet Stop cancels the job, as docs/commissioning.md promises, from REST (the
dashboard's button), the PLC over Modbus and OPC UA; the robot stops, the cell stays Stopped. Without a job
Stop in Stopped stays refused. The robot is watched on the ABB fake's own motion state and the twin's arm.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from opcua_test_support import PASSWORD, call, ns_of, opcua_client
from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import AUTH, api_client, running_service, slow_moves
from test_commission_jobs import _command, _config, _laser_job_under_way, _wait_done

from cellctl.cell.packml import CommandNotAllowed, PackMLMachine
from cellctl.domain import EventKind, PackMLCommand, PackMLState
from cellctl.service.compose import Service

pytestmark = pytest.mark.timeout(180)

ACCEPTED, NOT_ALLOWED = 0, 1  # docs/plc_register_map.md, Codes: cmd_result


async def _robot_still(service: Service, watch_s: float = 0.6) -> bool:
    """No move runs on the ABB fake's robot nor on the twin's arm within 0.1 s (the fake answers STOP, then halts
    its move at its next turn), and none for ``watch_s`` after: the arm's true pose stays where it stopped."""
    fake = service.extras["fakes"]["robot"].robot  # type: ignore[attr-defined]
    arm = service.extras["twin"].cell.arm  # type: ignore[attr-defined]
    deadline = time.monotonic() + 0.1
    while fake.moving or arm.moving():
        if time.monotonic() > deadline:
            return False
        await asyncio.sleep(0.005)
    stood = np.array(arm.true_pose())
    end = time.monotonic() + watch_s
    while time.monotonic() < end:
        if fake.moving or arm.moving():
            return False
        await asyncio.sleep(0.02)
    return bool(np.array_equal(np.array(arm.true_pose()), stood))


async def _ended_cancelled_by_stop(client: httpx.AsyncClient, service: Service, job: dict[str, Any]) -> dict[str, Any]:
    done = await _wait_done(client, job["id"], timeout_s=20)
    assert done["state"] == "cancelled" and "stop by" in done["error"] and "stopped" in done["error"], done
    assert (done["progress"] or {}).get("done", 0) < 200  # it did not run to its end
    assert service.orchestrator.machine.state is PackMLState.STOPPED
    return done


async def test_a_rest_stop_in_stopped_cancels_the_job_and_the_robot_stops(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config(answers="all")) as service, api_client(service) as client:
        slow_moves(service, 200.0)  # 0.2 of real time per simulated second: the job is under way when Stop comes
        assert await _command(client, "clear") == "STOPPED"
        job = await _laser_job_under_way(client)
        st = (await client.get("/status")).json()  # what the dashboard's buttons follow
        assert st["state"] == "STOPPED" and st["job"]["id"] == job["id"]
        assert "stop" in st["allowed_commands"] and "reset" in st["allowed_commands"], st["allowed_commands"]
        assert not await _robot_still(service, 1.0)  # the job moves the robot

        r = await client.post("/commands/stop", headers=AUTH)
        assert r.status_code == 200, r.text
        answer = r.json()
        assert answer["state"] == "STOPPED" and answer["command"] == "stop", answer
        assert f"cancelled commissioning job {job['id']} (laser)" in answer["effect"], answer
        assert await _robot_still(service)  # at once, not when the job has written its partial dataset
        await _ended_cancelled_by_stop(client, service, job)
        assert await _robot_still(service)

        entries = await service.store.audit_entries(limit=500)
        stop = [e for e in entries if e.action == "command:stop"]
        assert len(stop) == 1 and stop[0].actor == "operator" and (stop[0].state_before, stop[0].state_after) == ("STOPPED", "STOPPED")
        cancel = [e for e in entries if e.action == "job.cancel"]
        assert len(cancel) == 1 and cancel[0].params == {"job_id": job["id"], "reason": "stop by operator in stopped"}, cancel
        # The job has ended: Stop in Stopped is the table's refusal again.
        assert (await client.get("/status")).json()["allowed_commands"] == ["abort", "reset"]
        r = await client.post("/commands/stop", headers=AUTH)
        assert r.status_code == 409 and "allowed here: Reset, Abort" in r.json()["detail"], r.text


async def test_stop_in_stopped_without_a_job_stays_refused(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        assert await _command(client, "clear") == "STOPPED"
        assert (await client.get("/status")).json()["allowed_commands"] == ["abort", "reset"]
        r = await client.post("/commands/stop", headers=AUTH)
        assert r.status_code == 409, r.text
        assert r.json()["detail"] == (
            "Stop refused in Stopped: the PackML state model does not allow it (allowed here: Reset, Abort)")
        assert "effect" not in (await client.post("/commands/reset", headers=AUTH)).json()  # a table edge's answer as before
        entries = await service.store.audit_entries(limit=500)
        assert not [e for e in entries if e.action == "command:stop"]


async def test_a_plc_stop_in_stopped_cancels_the_job(tmp_path: Path) -> None:
    cfg = _config(answers="all", plc={"enabled": True, "port": 0, "scan_period_s": 0.005, "heartbeat_alarm": False})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        modbus = AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1)  # type: ignore[attr-defined]
        assert await modbus.connect()
        plc = PlcClient(modbus, cfg.plc.float_word_order, unit_id=cfg.plc.unit_id)
        try:
            slow_moves(service, 200.0)
            assert (await plc.command(PackMLCommand.CLEAR))["cmd_result"] == ACCEPTED
            assert PackMLState((await plc.read_cell())["state_current"]) is PackMLState.STOPPED
            job = await _laser_job_under_way(client)
            stop = await plc.command(PackMLCommand.STOP)
            assert stop["cmd_result"] == ACCEPTED, stop
            assert PackMLState(stop["state_current"]) is PackMLState.STOPPED
            assert await _robot_still(service)
            await _ended_cancelled_by_stop(client, service, job)
            entries = await service.store.audit_entries(limit=500)
            assert [e.actor for e in entries if e.action == "command:stop"] == ["line-plc"]
            # No job now: the table's refusal, invalid in state.
            assert (await plc.command(PackMLCommand.STOP))["cmd_result"] == NOT_ALLOWED
        finally:
            modbus.close()


async def test_an_opcua_stop_in_stopped_cancels_the_job(tmp_path: Path) -> None:
    from asyncua import ua

    opcua = {"enabled": True, "port": 0, "security_policies": ["Basic256Sha256_SignAndEncrypt"], "allow_anonymous": False,
             "users": [{"name": "operator", "password": PASSWORD}]}  # fmt: skip
    async with running_service(tmp_path, _config(answers="all", opcua=opcua)) as service, api_client(service) as client:
        async with opcua_client(service, tmp_path) as ua_client:
            ns = await ns_of(ua_client)
            slow_moves(service, 200.0)
            assert await _command(client, "clear") == "STOPPED"
            job = await _laser_job_under_way(client)
            await call(ua_client, ns, "BaseStateMachine.MachineState.Stop")  # Good: no BadInvalidState
            assert await _robot_still(service)
            await _ended_cancelled_by_stop(client, service, job)
            with pytest.raises(ua.uaerrors.BadInvalidState):  # no job now: refused as the table says
                await call(ua_client, ns, "BaseStateMachine.MachineState.Stop")


def _slow_calibration_read(service: Service) -> None:
    """A slow disk: the job's read of the set in use takes 300 ms (the job is starting meanwhile)."""
    store = service.jobs.calibration_store
    read = store.current

    def slow_read() -> Any:
        time.sleep(0.3)
        return read()

    store.current = slow_read  # type: ignore[method-assign]


async def test_a_stop_in_stopped_while_a_job_starts_cancels_it_once_started(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config(answers="all")) as service, api_client(service) as client:
        slow_moves(service, 200.0)
        assert await _command(client, "clear") == "STOPPED"
        _slow_calibration_read(service)
        submit = asyncio.create_task(client.post("/jobs", json={"procedure": "laser", "options": {"poses": 200}}, headers=AUTH))
        await asyncio.sleep(0.1)  # its state check passed; it is reading the set
        r = await client.post("/commands/stop", headers=AUTH)
        started = await submit
        assert started.status_code == 201, started.text
        job = started.json()
        assert r.status_code == 200 and f"cancelled commissioning job {job['id']}" in r.json()["effect"], r.text
        await _ended_cancelled_by_stop(client, service, job)
        assert await _robot_still(service)


async def test_a_stop_in_idle_while_a_job_starts_cancels_it_once_started(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config(answers="all")) as service, api_client(service) as client:
        slow_moves(service, 200.0)
        await _command(client, "clear")
        assert await _command(client, "reset") == "IDLE"
        _slow_calibration_read(service)
        submit = asyncio.create_task(client.post("/jobs", json={"procedure": "laser", "options": {"poses": 200}}, headers=AUTH))
        await asyncio.sleep(0.1)
        assert await _command(client, "stop") == "STOPPED"  # Idle's Stop edge, while the job starts
        started = await submit
        assert started.status_code == 201, started.text
        done = await _wait_done(client, started.json()["id"], timeout_s=20)
        assert done["state"] == "cancelled" and "stopping (stop by operator)" in done["error"], done
        assert await _robot_still(service)


async def test_a_taker_carries_out_a_command_the_table_has_no_edge_for() -> None:
    from cellctl.cell.packml import TakenCommand

    machine = PackMLMachine(initial_state=PackMLState.STOPPED)
    events: list[Any] = []
    machine.subscribe(events.append)
    job = {"running": False}
    done: list[tuple[str, str]] = []

    async def cancel(actor: str, source: str) -> str:
        done.append((actor, source))
        return "cancelled the job"

    machine.add_taker(PackMLCommand.STOP, lambda s, c: cancel if job["running"] and s is PackMLState.STOPPED else None)
    assert PackMLCommand.STOP not in machine.allowed_commands()
    with pytest.raises(CommandNotAllowed):
        await machine.command(PackMLCommand.STOP, actor="op", source="rest")
    job["running"] = True
    assert machine.status().allowed_commands == {PackMLCommand.STOP, PackMLCommand.RESET, PackMLCommand.ABORT}
    ev = await machine.command(PackMLCommand.STOP, actor="op", source="rest")
    assert isinstance(ev, TakenCommand) and ev.effect == "cancelled the job" and done == [("op", "rest")]
    assert ev.state_before is ev.state_after is PackMLState.STOPPED and machine.state is PackMLState.STOPPED
    assert [(e.kind, e.command, e.state_after) for e in events] == [(EventKind.COMMAND, PackMLCommand.STOP, PackMLState.STOPPED)]
    # A taker is asked only where the table has no edge: Reset keeps its edge.
    await machine.command(PackMLCommand.RESET, actor="op", source="rest")
    assert machine.state is PackMLState.RESETTING
