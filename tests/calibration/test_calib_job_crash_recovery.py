"""The service dies right after a job stored its calibration-set version, before the job's record said so:
after the restart the record names that version (version_after) and says it was stored before the stop."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from service_test_support import api_client, running_service, sim_config

TESTS = Path(__file__).resolve().parents[1]
SECTIONS: dict[str, dict[str, Any]] = {
    "calibration": {"source": "set", "auto_calibrate_in_sim": False},
    "sim": {"time_scale": 0.001},
    "sim.operator": {"answers": "all"},
    "plc": {"enabled": False},
}

# The first life of the service: a real laser job whose process dies (os._exit, as SIGKILL or a power loss)
# the moment the new version is stored. It prints the job id and the version the store returned.
DYING_SERVICE = """
import asyncio, json, os, sys
from pathlib import Path
import cellctl.commissioning.jobs as jobs_mod
from cellctl.bench.accuracy import settle
from cellctl.domain import PackMLCommand
from cellctl.service import build_service
from service_test_support import sim_config

real = jobs_mod.record
job_id = None

def record_then_die(*args, **kwargs):
    saved = real(*args, **kwargs)
    print(json.dumps({"job": job_id, "version": saved.version}), flush=True)
    os._exit(9)

jobs_mod.record = record_then_die

async def main():
    global job_id
    service = await build_service(sim_config(**json.loads(sys.argv[2])), workdir=Path(sys.argv[1]))
    await service.start()
    await service.orchestrator.command(PackMLCommand.CLEAR, actor="test", source="test")
    await settle(service.orchestrator)
    rec = await service.jobs.submit("laser", {"poses": 120}, actor="test", source="test")
    job_id = rec.id
    await service.jobs.wait(rec.id, 60)
    print("the job ended without storing a version", flush=True)

asyncio.run(main())
"""


def _die_after_the_commit(workdir: Path) -> dict[str, int]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS / "service"), str(TESTS), os.environ.get("PYTHONPATH", "")]),
           "TMPDIR": str(workdir)}  # the LK-G fake's link folder, which a process that dies leaves behind: in the test's tmp_path
    run = subprocess.run([sys.executable, "-c", DYING_SERVICE, str(workdir), json.dumps(SECTIONS)],
                         capture_output=True, text=True, timeout=120, env=env)  # fmt: skip
    assert run.returncode == 9, run.stdout + run.stderr
    return json.loads(run.stdout.strip().splitlines()[-1])


async def test_a_version_stored_before_the_stop_is_the_jobs_version_after_restart(tmp_path: Path) -> None:
    died = _die_after_the_commit(tmp_path)
    async with running_service(tmp_path, sim_config(**SECTIONS)) as service, api_client(service) as client:
        root = service.jobs.calibration_store.root
        job = (await client.get(f"/jobs/{died['job']}")).json()
    # The truth is on disk: the pointer names the dead process's version, and that file's note names the job.
    assert (root / "current").read_text().strip() == f"set-{died['version']:06d}.json"
    assert json.loads((root / f"set-{died['version']:06d}.json").read_text())["note"] == f"laser: job {died['job']}"
    assert job["version_after"] == died["version"], job
    assert job["state"] == "interrupted", job
    assert f"after it stored calibration set version {died['version']} (it is the set in use)" in job["error"], job
