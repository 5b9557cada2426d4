"""A service job whose new version finds the calibration store held by another process (an offline
``cellctl calibrate --dataset``) ends failed with the store's message, not as a software fault; the set is unchanged."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from service_test_support import AUTH, api_client, job_ended, running_service, sim_config
from test_calib_store_lock import _other_writer

import cellctl.calibration.set_lock as set_lock

CONFIG = {"calibration": {"source": "set", "auto_calibrate_in_sim": False}, "sim": {"time_scale": 0.001},
          "sim.operator": {"answers": "all"}, "plc": {"enabled": False}}  # fmt: skip


async def test_a_job_refused_by_a_busy_store_fails_naming_the_other_process(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(set_lock, "LOCK_WAIT_S", 0.3)
    async with running_service(tmp_path, sim_config(**CONFIG)) as service, api_client(service) as client:
        root = service.jobs.calibration_store.root
        root.mkdir(parents=True, exist_ok=True)
        before = sorted(p.name for p in root.glob("set-*.json"))
        other = _other_writer(root, hold_s=60.0)
        try:
            assert (await client.post("/commands/clear", headers=AUTH)).status_code == 200
            while (await client.get("/status")).json()["state"].endswith("ING"):
                await asyncio.sleep(0.01)
            r = await client.post("/jobs", json={"procedure": "laser", "options": {"poses": 120}}, headers=AUTH)
            assert r.status_code == 201, r.text
            job = await job_ended(client, r.json()["id"])
        finally:
            other.kill()
            other.wait()
    assert job["state"] == "failed" and job["version_after"] is None, job
    assert f"the calibration store {root} is in use by another process (pid {other.pid})" in job["error"], job
    assert "software fault" not in job["error"] and "try again" in job["error"], job
    assert sorted(p.name for p in root.glob("set-*.json")) == before  # the other writer was killed before it wrote
    assert job["dataset"] and Path(job["dataset"]).is_dir()  # the collected dataset is kept for `--dataset`
