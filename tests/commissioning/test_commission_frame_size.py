"""A camera delivering another frame size than the procedure computes with (binning left on, a swapped camera)
is refused at its first frame, naming both sizes and the setting to change: the camera procedure against
``layout.camera`` (else it would calibrate a lens every cycle then refuses, and recalibrating would not help),
the later ones against the calibrated lens.

The simulated cell's camera is wrapped so its frames come binned 4 x 4 (2048 x 2048 -> 512 x 512 px)."""

from __future__ import annotations

import asyncio
import dataclasses
from pathlib import Path
from typing import Any

import pytest
from service_test_support import AUTH, BinnedCamera, api_client, job_ended, running_service, sim_config

from cellctl.calibration.calibration_set import CalibrationStore

pytestmark = pytest.mark.timeout(240)


async def _job(client: Any, procedure: str) -> dict[str, Any]:
    r = await client.post("/jobs", json={"procedure": procedure}, headers=AUTH)
    assert r.status_code == 201, r.text
    return await job_ended(client, r.json()["id"])


async def test_a_binned_camera_is_refused_by_the_camera_and_hand_eye_procedures_naming_the_fix(tmp_path: Path) -> None:
    cfg = sim_config(**{"calibration": {"source": "set", "auto_calibrate_in_sim": False}, "plc": {"enabled": False},
                        "sim.operator": {"answers": "all"}})  # fmt: skip
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        binning = {"on": True}
        camera = BinnedCamera(service.jobs.devices.camera, lambda: binning["on"])
        service.jobs.devices = dataclasses.replace(service.jobs.devices, camera=camera)
        assert (await client.post("/commands/clear", headers=AUTH)).status_code == 200
        await asyncio.sleep(0.1)

        job = await _job(client, "camera")
        assert job["state"] == "refused" and camera.sizes == [(512, 512)], (job, camera.sizes)
        assert "frame_size" in job["error"] and "512 x 512 px" in job["error"] and "2048 x 2048 px" in job["error"], job
        assert "layout.camera" in job["error"] and "binning" in job["error"], job
        assert "fx, fy" in job["error"] and "divides each by b" in job["error"], job  # binning scales the focal lengths too
        assert job["version_after"] is None and CalibrationStore(service.jobs.calibration_store.root).current() is None

        binning["on"] = False  # the camera's binning set back: the lens is calibrated at the full frame
        job = await _job(client, "camera")
        assert job["state"] == "done", job
        assert set(camera.sizes[1:]) == {(2048, 2048)}
        version = job["version_after"]

        binning["on"] = True  # left on again before the hand-eye: refused against the calibrated lens
        grabs = len(camera.sizes)
        job = await _job(client, "hand_eye")
        assert job["state"] == "refused" and camera.sizes[grabs:] == [(512, 512)], (job, camera.sizes[grabs:])
        assert "camera calibration is for 2048 x 2048 px" in job["error"] and "512 x 512 px" in job["error"], job
        assert "cellctl calibrate camera" in job["error"], job
        assert CalibrationStore(service.jobs.calibration_store.root).current().version == version
