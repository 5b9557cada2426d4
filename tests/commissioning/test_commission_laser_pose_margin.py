"""The laser job's pose count against its dataset gate: the fewest poses a job may ask for leave readings to spare,
and a job refused for too few readings says which flag to raise and to what.

The simulated cell's real composition over its REST API (the LK-G driver over its fake); a few readings are
knocked out as a car body's edge or a stray reflection would (the sensor reports out of range).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
from service_test_support import AUTH, api_client, running_service
from test_commission_jobs import _command, _config, _start, _wait_done

from cellctl.ports import DistanceReading, LaserStatus
from cellctl.service.compose import Service


def _knock_out(service: Service, lost: Callable[[int], bool]) -> None:
    """The laser's k-th reading (from 0) comes back out of range when ``lost(k)``."""
    laser = service.jobs.devices.laser
    read, count = laser.read, [0]

    async def reading(*, timeout_s: float) -> DistanceReading:
        k, count[0] = count[0], count[0] + 1
        got = await read(timeout_s=timeout_s)
        return DistanceReading(None, LaserStatus.OVER_RANGE_FAR, time.monotonic()) if lost(k) else got

    laser.read = reading  # type: ignore[method-assign]


async def _fewest_poses(client: httpx.AsyncClient) -> int:
    """The fewest laser poses a job may ask for, asked of the service while the cell is still Aborted (bisection over
    POST /jobs: 422 names a bad option, 409 a good one refused only for the cell's state; nothing is planned)."""
    lo, hi = 1, 5000  # refused at lo, allowed at hi
    while hi - lo > 1:
        mid = (lo + hi) // 2
        r = await client.post("/jobs", json={"procedure": "laser", "options": {"poses": mid}}, headers=AUTH)
        assert r.status_code in (409, 422) and (r.status_code == 422) == ("options.poses" in r.text), r.text
        lo, hi = (lo, mid) if r.status_code == 409 else (mid, hi)
    return hi


async def test_a_job_at_the_fewest_poses_allowed_survives_a_handful_of_lost_readings(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config(answers="all")) as service, api_client(service) as client:
        gate = service.config.calibration.procedure.laser.min_poses
        fewest = await _fewest_poses(client)
        await _command(client, "clear")
        _knock_out(service, lambda k: k % 14 == 3)  # 7 readings in 100 lost
        job = await _wait_done(client, (await _start(client, "laser", poses=fewest))["id"])
        assert job["state"] == "done", job["error"]
        assert job["result"]["quality"]["readings_without_value"] >= fewest // 14 and fewest > gate


async def test_a_job_short_of_readings_names_the_flag_and_how_many_poses_then_runs_with_them(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config(answers="all")) as service, api_client(service) as client:
        gate = service.config.calibration.procedure.laser.min_poses
        fewest = await _fewest_poses(client)
        await _command(client, "clear")
        _knock_out(service, lambda k: k % 4 == 0)  # a quarter of the readings lost: fewer than the gate's
        job: dict[str, Any] = await _wait_done(client, (await _start(client, "laser", poses=fewest))["id"])
        assert job["state"] == "refused" and "too_few_poses" in job["error"], job
        found = re.search(r"--poses (\d+)", job["error"])
        assert found and "options.poses" in job["error"], job["error"]
        ask = int(found.group(1))
        assert f"{ask - fewest} more" in job["error"], job["error"]
        # At the same loss, the poses it names give the gate its readings: the job runs to the end.
        assert ask * 3 // 4 >= gate, ask
        job = await _wait_done(client, (await _start(client, "laser", poses=ask))["id"])
        assert job["state"] == "done", job["error"]
