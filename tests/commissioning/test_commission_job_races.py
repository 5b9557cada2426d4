"""A job against what can happen meanwhile: a PackML Start while the job starts is held back, and a cancel while
the new calibration version is written ends the job done with the version it stored (the set in use then)."""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from service_test_support import AUTH, api_client, running_service
from test_commission_jobs import _command, _config, _start, _wait_done

import cellctl.commissioning.jobs as jobs_mod
from cellctl.calibration.calibration_set import CalibrationStore


async def test_a_start_while_a_job_starts_is_held_back(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        await _command(client, "clear")
        assert await _command(client, "reset") == "IDLE"
        store = service.jobs.calibration_store
        read = store.current

        def slow_read() -> Any:  # a slow disk: the job's read of the set in use takes 300 ms
            time.sleep(0.3)
            return read()

        store.current = slow_read  # type: ignore[method-assign]
        submit = asyncio.create_task(client.post("/jobs", json={"procedure": "laser", "options": {"poses": 120}}, headers=AUTH))
        await asyncio.sleep(0.1)  # its state check passed; it is reading the set
        start = await client.post("/commands/start", headers=AUTH)  # the PLC's Start, say
        assert (await submit).status_code == 201
        assert start.status_code == 409 and "a commissioning job (laser) is starting" in start.text, start.text
        assert (await client.get("/status")).json()["state"] == "IDLE"


async def test_a_cancel_while_the_new_version_is_written_ends_the_job_done_with_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    writing = threading.Event()
    record = jobs_mod.record

    def slow_record(*args: Any, **kwargs: Any) -> Any:  # the set file's and the pointer's fsyncs on a slow disk
        writing.set()
        time.sleep(0.5)
        return record(*args, **kwargs)

    monkeypatch.setattr(jobs_mod, "record", slow_record)
    async with running_service(tmp_path, _config(answers="all")) as service, api_client(service) as client:
        await _command(client, "clear")
        job = await _start(client, "laser", poses=120)
        while not writing.is_set():
            await asyncio.sleep(0.01)
        assert (await client.post(f"/jobs/{job['id']}/cancel", headers=AUTH)).status_code == 200
        done = await _wait_done(client, job["id"])
        current = CalibrationStore(service.jobs.calibration_store.root).current()
        assert current is not None and done["state"] == "done" and done["version_after"] == current.version, done
        assert "it was stored and is in use" in done["result"]["cancel"]
