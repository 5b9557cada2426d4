"""A job whose device the watchdog has lost is refused at start (and its plan too): it names the device and the
watchdog's last error, asks nothing and moves nothing. A job that does not use the lost device is not held back.

The simulated cell's real composition over its REST API, the LK-G protocol fake silenced; the peers are /status
(the watchdog's view) and the ABB fake's record of the lines it received (the wire protocol's motion verbs).
"""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest
from abb_robot.protocol import VERBS
from service_test_support import AUTH, api_client, sim_config
from shared_support import eventually

from cellctl.commissioning.registry import ALL_PROCEDURES, DEVICES_USED
from cellctl.ports import DeviceRejected
from cellctl.service import build_service

pytestmark = pytest.mark.timeout(90)

MOVING = {v.name for v in VERBS.values() if v.kind in ("motion", "staging", "io")}  # a move, its target, the gripper


async def _stopped(client: httpx.AsyncClient) -> bool:
    return (await client.get("/status")).json()["state"] == "STOPPED"


async def _laser_link(client: httpx.AsyncClient) -> str:
    return str((await client.get("/status")).json()["devices"]["laser"]["link"])


async def test_a_job_using_the_lost_laser_is_refused_before_any_prompt_or_move(tmp_path: Path) -> None:
    cfg = sim_config(plc={"enabled": False}, **{"alarms.watchdog": {"period_s": 0.2, "timeout_s": 0.15, "miss_threshold": 2}})
    service = await build_service(cfg, workdir=tmp_path)
    laser, robot = service.extras["fakes"]["laser"], service.extras["fakes"]["robot"]
    laser.silence(count=None)  # the LK-G controller no longer answers
    await service.start()
    try:
        async with api_client(service) as client:

            async def lost() -> bool:
                return await _laser_link(client) == "lost"

            await eventually("the watchdog sees the laser lost", lost)
            assert (await client.post("/commands/clear", headers=AUTH)).status_code == 200
            await eventually("Stopped: a job may start as far as the state goes", lambda: _stopped(client))
            last_error = "no valid reply to MS,01"  # the LK-G's measurement request, which the silenced fake ignores
            before = len(robot.server.lines_received)
            for procedure in ("laser", "teaching", "verify"):  # each reads the laser
                for path in ("/jobs/plan", "/jobs"):
                    r = await client.post(path, json={"procedure": procedure, "options": {}}, headers=AUTH)
                    assert r.status_code == 409, (procedure, path, r.status_code, r.text)
                    detail = r.json()["detail"]
                    assert "the watchdog has lost the laser" in detail and last_error in detail, detail
                    assert "devices.laser.port" in detail, detail  # what to check
            # The camera job does not use the laser: its plan is given.
            assert (await client.post("/jobs/plan", json={"procedure": "camera"}, headers=AUTH)).status_code == 200
            assert (await client.get("/jobs")).json() == []  # no job was created: no prompt could be asked
            sent = [line.split()[1] for line in robot.server.lines_received[before:] if len(line.split()) > 1]
            assert not [v for v in sent if v in MOVING], sent  # "<id> <VERB> ...": no move, target or gripper line
    finally:
        await service.stop()


async def test_a_camera_job_is_refused_while_the_camera_is_lost_and_the_laser_job_is_not(tmp_path: Path) -> None:
    cfg = sim_config(plc={"enabled": False}, **{"alarms.watchdog": {"period_s": 0.2, "timeout_s": 0.15, "miss_threshold": 2}})
    service = await build_service(cfg, workdir=tmp_path)
    camera = service.orchestrator.devices.camera

    async def rejected(*, timeout_s: float) -> float:  # as the report's camera: a frame size other than layout.camera
        raise DeviceRejected("camera", "frame 512 x 512 px, not 2048 x 2048 px (binning?)")

    camera.ping = rejected  # the watchdog pings this object
    await service.start()
    try:
        async with api_client(service) as client:

            async def lost() -> bool:
                return str((await client.get("/status")).json()["devices"]["camera"]["link"]) == "lost"

            await eventually("the watchdog sees the camera lost", lost)
            assert (await client.post("/commands/clear", headers=AUTH)).status_code == 200
            await eventually("Stopped", lambda: _stopped(client))
            for procedure in ("camera", "hand_eye", "pixel_map"):
                r = await client.post("/jobs", json={"procedure": procedure}, headers=AUTH)
                assert r.status_code == 409, (procedure, r.text)
                detail = r.json()["detail"]
                assert "the watchdog has lost the camera" in detail and "512 x 512 px, not 2048 x 2048 px" in detail, detail
                assert "devices.camera" in detail and "layout.camera" in detail, detail
            assert (await client.get("/jobs")).json() == []
            assert (await client.post("/jobs/plan", json={"procedure": "laser"}, headers=AUTH)).status_code == 200
    finally:
        await service.stop()


def test_every_procedure_names_the_devices_it_uses() -> None:
    assert set(DEVICES_USED) == set(ALL_PROCEDURES)
    assert all(used[0] == "robot" and set(used) <= {"robot", "camera", "laser"} for used in DEVICES_USED.values())
