"""A damaged calibration set in use: the service still starts (alarm 1305 and /status say how to restore it), and a
job started or planned on it is refused with that text, never a 500."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from service_test_support import AUTH, api_client, running_service, sim_config
from test_calib_damaged_set import write_valid_set

DAMAGED = "{ this is not json"  # e.g. a power cut during a backup restore


def _cfg(cal_dir: Path) -> Any:
    return sim_config(calibration={"source": "set", "auto_calibrate_in_sim": False, "directory": str(cal_dir)},
                      plc={"enabled": False}, sim={"time_scale": 0.001})  # fmt: skip


async def test_the_service_starts_on_a_damaged_set_and_says_how_to_restore_it(tmp_path: Path) -> None:
    cal_dir = tmp_path / "cal"
    write_valid_set(cal_dir)
    (cal_dir / "set-000005.json").write_text(DAMAGED)
    async with running_service(tmp_path / "work", _cfg(cal_dir)) as service, api_client(service) as client:
        problems = (await client.get("/status")).json()["calibration"]["problems"]
        assert "not valid JSON" in problems[0] and "set-000004.json" in problems[0], problems


async def test_a_job_started_or_planned_on_a_damaged_set_is_refused_naming_the_fix(tmp_path: Path) -> None:
    cal_dir = tmp_path / "cal"
    write_valid_set(cal_dir)
    async with running_service(tmp_path / "work", _cfg(cal_dir)) as service, api_client(service) as client:
        (cal_dir / "set-000005.json").write_text(DAMAGED)
        assert (await client.post("/commands/clear", headers=AUTH)).status_code == 200
        for _ in range(200):
            if (await client.get("/status")).json()["state"] == "STOPPED":
                break
            await asyncio.sleep(0.01)
        for url in ("/jobs", "/jobs/plan"):
            r = await client.post(url, json={"procedure": "camera"}, headers=AUTH)
            assert r.status_code == 409, (url, r.status_code, r.text)
            assert "the calibration set in use is damaged" in r.text and "set-000004.json" in r.text, r.text
        assert service.jobs.running() is None


async def test_a_mistyped_pointer_is_a_damaged_set_not_a_failed_start(tmp_path: Path) -> None:
    """The restore advice says to edit the pointer by hand; a typo or an empty file there starts the service with the
    same advice, the newest set named (it used to end `serve` with a traceback, the error raised again inside its own handler)."""
    cal_dir = tmp_path / "cal"
    write_valid_set(cal_dir)
    for k, pointer in enumerate(("set-000004.jsn\n", "")):
        (cal_dir / "current").write_text(pointer)
        async with running_service(tmp_path / f"work{k}", _cfg(cal_dir)) as service, api_client(service) as client:
            problems = (await client.get("/status")).json()["calibration"]["problems"]
            assert "the calibration set in use is damaged" in problems[0] and "(e.g. set-000005.json)" in problems[0], problems
