"""Fault injection: each device fault, where the cell ends, what it says, and that it recovers without a restart.

The simulated cell runs the real LK-G and ABB drivers over their protocol fakes; the faults are
injected there (the LK-G fake falls silent or answers garbage, the ABB fake drops its client),
in the twin's camera (a frame that never comes) and by PackML commands while the robot moves.
For each row: the PackML state reached, the alarm and the first-out stop reason, the cycle's
record (its error code is what the PLC publishes), recovery with the documented commands
(acknowledge, then Unhold / Reset / Clear as the state asks), a following cycle that installs,
and no install repeated. (kill -9 during the install is tests/service/test_service_crash.py;
a PLC heartbeat lost while the robot moves is tests/service/test_service_plc_faults.py.)
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_test_support import AUTH, api_client, running_service, sim_config, slow_moves
from shared_support import eventually

from cellctl.cell.alarms import AlarmCode

pytestmark = pytest.mark.timeout(120)

RECOVERY = {"HELD": ["unhold"], "STOPPED": ["reset", "start"], "ABORTED": ["clear", "reset", "start"], "IDLE": ["start"],
            "SUSPENDED": ["unsuspend"]}  # fmt: skip


def _config(**extra: dict[str, Any]) -> Any:
    sections: dict[str, dict[str, Any]] = {
        "plc": {"enabled": False},
        "alarms.watchdog": {"period_s": 0.2, "timeout_s": 0.15, "miss_threshold": 2},
        "process.motion": {"grab_timeout_s": 1.0, "read_timeout_s": 1.0},
    }
    sections.update(extra)
    return sim_config(**sections)


async def _state(client: httpx.AsyncClient) -> str:
    return str((await client.get("/status")).json()["state"])


async def _settled(client: httpx.AsyncClient) -> str:
    await eventually("the cell leaves its acting state", lambda: _not_acting(client))
    return await _state(client)


async def _not_acting(client: httpx.AsyncClient) -> bool:
    return not (await _state(client)).endswith("ING")


async def _command(client: httpx.AsyncClient, name: str) -> httpx.Response:
    r = await client.post(f"/commands/{name}", headers=AUTH)
    await _settled(client)
    return r


async def _recover(client: httpx.AsyncClient) -> None:
    """What the operator does: acknowledge the alarms, then the commands the state asks for, to Execute."""
    assert (await client.post("/alarms/acknowledge-all", headers=AUTH)).status_code == 200
    state = await _settled(client)
    for cmd in RECOVERY.get(state, []):
        r = await _command(client, cmd)
        assert r.status_code == 200, f"{cmd} in {state}: {r.text}"
    assert await _state(client) == "EXECUTE"


async def _to_execute(client: httpx.AsyncClient) -> None:
    for cmd in ("clear", "reset", "start"):
        assert (await _command(client, cmd)).status_code == 200
    assert await _state(client) == "EXECUTE"


async def _submit(client: httpx.AsyncClient, key: str) -> int:
    r = await client.post("/cycle", json={"recipe": "side-window", "part_id": key}, headers={**AUTH, "Idempotency-Key": key})
    assert r.status_code == 202, r.text
    return int(r.json()["cycle_id"])


async def _finished(client: httpx.AsyncClient, cycle_id: int, timeout_s: float = 60.0) -> dict[str, Any]:
    rec: dict[str, Any] = {}

    async def done() -> bool:
        nonlocal rec
        rec = (await client.get(f"/cycles/{cycle_id}")).json()
        return rec["state"] in ("done", "failed", "interrupted")

    await eventually(f"cycle {cycle_id} ends", done, timeout_s)
    return rec


async def _alarms(client: httpx.AsyncClient) -> dict[str, Any]:
    return dict((await client.get("/alarms")).json())


def _codes(alarms: dict[str, Any], *, active: bool | None = None) -> set[int]:
    return {a["code"] for a in alarms["current"] if active is None or a["active"] == active}


async def _installs_once(client: httpx.AsyncClient) -> None:
    """A cycle after the recovery installs; no cycle's install ever started twice."""
    cid = await _submit(client, f"after-{time.monotonic_ns()}")
    rec = await _finished(client, cid)
    assert rec["state"] == "done", (rec["error"], rec["true_error"])
    items = (await client.get("/cycles?limit=50")).json()
    started = [c["id"] for c in items if c.get("install_started_at")]
    assert len(started) == len(set(started))


async def _while_moving(service: Any) -> None:
    robot = service.orchestrator.robot

    async def moving() -> bool:
        return bool(robot.moving)

    await eventually("the robot moves", moving)


async def test_laser_silence_holds_then_recovers_when_it_answers_again(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        laser = service.extras["fakes"]["laser"]
        await _to_execute(client)
        laser.silence(count=None)
        rec = await _finished(client, await _submit(client, "silent"))
        assert rec["install_started_at"] is None
        assert await _settled(client) == "HELD"
        # First-out: whichever saw it first, the cycle's failed reading or the watchdog's missed pings;
        # the record (and so the PLC) carries the same code as the stop reason.
        al = await _alarms(client)
        assert al["stop_reason"]["code"] in (int(AlarmCode.LASER_READ_FAILED), int(AlarmCode.LASER_LOST))
        assert rec["state"] == "failed" and rec["result"]["error_code"] == al["stop_reason"]["code"], rec
        await eventually("the watchdog sees the laser lost", lambda: _has(client, AlarmCode.LASER_LOST, active=True))
        r = await client.post("/commands/unhold", headers=AUTH)
        assert r.status_code == 409  # not while the laser is silent
        laser.speak()
        await eventually("the watchdog sees the laser back", lambda: _has(client, AlarmCode.LASER_LOST, active=False))
        await _recover(client)
        await _installs_once(client)


async def _has(client: httpx.AsyncClient, code: AlarmCode, *, active: bool) -> bool:
    alarms = await _alarms(client)
    now = [a for a in alarms["current"] if a["code"] == int(code) and a["source"] != "cycle"]
    return any(a["active"] for a in now) if active else not any(a["active"] for a in now)


async def test_laser_garbage_holds_then_recovers(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        laser = service.extras["fakes"]["laser"]
        await _to_execute(client)
        laser.garble("replace", count=None)
        rec = await _finished(client, await _submit(client, "garbage"))
        assert await _settled(client) == "HELD"
        al = await _alarms(client)
        assert al["stop_reason"]["code"] in (int(AlarmCode.LASER_READ_FAILED), int(AlarmCode.LASER_LOST))
        assert rec["state"] == "failed" and rec["result"]["error_code"] == al["stop_reason"]["code"], rec
        laser.clear_faults()
        await eventually("the laser answers the watchdog", lambda: _has(client, AlarmCode.LASER_LOST, active=False))
        await _recover(client)
        await _installs_once(client)


async def test_a_camera_grab_timeout_holds_then_recovers(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        await asyncio.to_thread(service.orchestrator.calibration.cycle_calibration)  # the oracle renders its template first
        renderer = service.extras["twin"].renderer
        original = renderer.render
        slow = {"left": 1}

        def render(*a: Any, **k: Any) -> Any:
            if slow["left"] > 0:
                slow["left"] -= 1
                time.sleep(1.5)  # longer than process.motion.grab_timeout_s
            return original(*a, **k)

        renderer.render = render
        await _to_execute(client)
        rec = await _finished(client, await _submit(client, "no-frame"))
        assert rec["state"] == "failed" and rec["result"]["error_code"] == int(AlarmCode.CAMERA_GRAB_FAILED), rec
        assert await _settled(client) == "HELD"
        await _recover(client)
        await _installs_once(client)


async def test_the_robot_link_dropped_mid_move_aborts_then_recovers(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        slow_moves(service, 300.0)
        await _to_execute(client)
        cid = await _submit(client, "drop")
        await _while_moving(service)
        service.extras["fakes"]["robot"].drop_client()
        rec = await _finished(client, cid)
        assert rec["state"] == "failed" and rec["result"]["error_code"] == int(AlarmCode.ROBOT_FAULT), rec
        assert rec["install_started_at"] is None
        assert await _settled(client) == "ABORTED"
        assert (await _alarms(client))["stop_reason"]["code"] == int(AlarmCode.ROBOT_FAULT)
        slow_moves(service, 1.0 / 300.0)
        await eventually("the robot link is back", lambda: _device_up(client, "robot"))
        await _recover(client)
        await _installs_once(client)


async def _device_up(client: httpx.AsyncClient, name: str) -> bool:
    return bool((await client.get("/status")).json()["devices"][name]["link"] == "up")


@pytest.mark.parametrize(("command", "state", "code"), [
    ("hold", "HELD", AlarmCode.CYCLE_STOPPED), ("stop", "STOPPED", AlarmCode.CYCLE_STOPPED), ("abort", "ABORTED", AlarmCode.CYCLE_STOPPED),
])  # fmt: skip
async def test_a_command_during_motion_ends_in_its_state_with_the_cycle_stopped_by_it(
    tmp_path: Path, command: str, state: str, code: AlarmCode
) -> None:
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        slow_moves(service, 300.0)
        await _to_execute(client)
        cid = await _submit(client, command)
        await _while_moving(service)
        assert (await _command(client, command)).status_code == 200
        rec = await _finished(client, cid)
        assert rec["state"] == "failed" and rec["error"].startswith("stopped: the cell went to"), rec
        assert f"{command} by operator" in rec["error"] and rec["result"]["error_code"] == int(code)
        assert await _state(client) == state
        al = await _alarms(client)
        assert int(AlarmCode.ROBOT_FAULT) not in _codes(al) and int(AlarmCode.TASK_FAILED) not in _codes(al), al
        assert not service.extras["fakes"]["robot"].robot.moving  # the controller's own view: it stands
        slow_moves(service, 1.0 / 300.0)
        await _recover(client)
        await _installs_once(client)
