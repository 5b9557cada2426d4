"""A camera delivering another frame size than the calibrated lens (a swapped camera, one back from a power
cycle with binning 4) fails the cycle with the camera-grab alarm (1105, sensor lost: Hold), naming both sizes
and what to check, whichever grab of the cycle sees it (the shoot, the inspection); never a software fault.

The simulated cell's camera is wrapped so its frames come binned 4 x 4 (2048 x 2048 -> 512 x 512 px)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from service_test_support import AUTH, BinnedCamera, api_client, back_to_execute, running_service, sim_config, to_execute
from shared_support import eventually

from cellctl.domain import CycleStep

pytestmark = pytest.mark.timeout(180)

CAMERA_GRAB_FAILED = 1105  # docs/alarm_reactions.md: camera_grab_failed, class sensor_lost, event
SOFTWARE_FAULT = 1501


def _binned_camera(service: Any, binned: Callable[[], bool]) -> BinnedCamera:
    orch = service.orchestrator
    camera = BinnedCamera(orch.devices.camera, binned)
    orch.devices = dataclasses.replace(orch.devices, camera=camera)
    return camera


async def _run_cycle(client: Any, key: str) -> dict[str, Any]:
    r = await client.post("/cycle", json={"recipe": "side-window", "part_id": key}, headers={**AUTH, "Idempotency-Key": key})
    assert r.status_code == 202, r.text
    cid = int(r.json()["cycle_id"])
    rec: dict[str, Any] = {}

    async def ended() -> bool:
        nonlocal rec
        rec = (await client.get(f"/cycles/{cid}")).json()
        return rec["state"] in ("done", "failed", "interrupted")

    await eventually(f"cycle {cid} ends", ended, 90.0)
    return rec


async def _held_with_the_camera_alarm(client: Any, rec: dict[str, Any], step: str) -> None:
    assert rec["state"] == "failed" and rec["result"]["error_code"] == CAMERA_GRAB_FAILED, (rec["error"], rec["result"])
    assert rec["current_step"] == step
    for text in (rec["error"], *(a["message"] for a in (await client.get("/alarms")).json()["current"]
                                 if a["code"] == CAMERA_GRAB_FAILED and a.get("cycle_id") == rec["id"])):  # fmt: skip
        assert "512 x 512 px" in text and "2048 x 2048 px" in text, text
        assert "Width/Height" in text and "binning" in text and "devices.camera.serial_number" in text, text
        assert "cellctl calibrate camera" in text, text
    alarms = (await client.get("/alarms")).json()
    mine = [a for a in alarms["current"] if a.get("cycle_id") == rec["id"]]
    assert [a["code"] for a in mine] == [CAMERA_GRAB_FAILED], mine
    assert mine[0]["category"] == "sensor_lost" and mine[0]["reaction"] == "hold", mine[0]
    assert SOFTWARE_FAULT not in {a["code"] for a in alarms["current"]}
    assert alarms["stop_reason"]["code"] == CAMERA_GRAB_FAILED
    async def held() -> bool:  # the record is written as the Hold begins: HOLDING may still stand a moment
        return bool((await client.get("/status")).json()["state"] == "HELD")

    await eventually("the cell HELD after the camera alarm's Hold", held, 10.0)


async def test_a_binned_camera_fails_the_shot_with_the_camera_alarm_and_holds(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        binning = {"on": True}
        camera = _binned_camera(service, lambda: binning["on"])
        await to_execute(client)
        rec = await _run_cycle(client, "binned")
        assert camera.sizes == [(512, 512)]  # one grab, refused at once
        await _held_with_the_camera_alarm(client, rec, "shoot")
        assert rec["install_started_at"] is None
        binning["on"] = False  # the camera's binning set back: acknowledge, Unhold, and the next cycle installs
        await back_to_execute(client)
        rec = await _run_cycle(client, "unbinned")
        assert rec["state"] == "done", (rec["error"], rec["result"])
        assert set(camera.sizes[1:]) == {(2048, 2048)}


async def test_a_camera_binned_before_the_inspection_fails_it_with_the_camera_alarm(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        machine = service.orchestrator.machine
        camera = _binned_camera(service, lambda: machine.cycle_step is CycleStep.INSPECT)
        await to_execute(client)
        rec = await _run_cycle(client, "binned-at-inspection")
        assert camera.sizes[-1] == (512, 512) and set(camera.sizes[:-1]) == {(2048, 2048)}
        assert rec["install_started_at"] is not None  # the glass went in; only its inspection image is refused
        await _held_with_the_camera_alarm(client, rec, "inspect")
