"""Drift checks in the service leave no more than ``calibration.procedure.verify.keep_datasets`` check datasets.

Each ``cellctl calibrate verify`` writes a dataset (about 47 MiB on the simulated cell); the cell asks for one every
``every_hours`` / ``every_cycles``, so unbounded they fill the disk. Peers: the file system (the folder's listing and
file sizes from os.stat) and the calibration set files read with json.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import os
from pathlib import Path
from typing import Any

import pytest
from service_test_support import AUTH, api_client, job_ended, running_service, sim_config

MIB = 1024**2
CELL = {"calibration": {"source": "set", "auto_calibrate_in_sim": False}, "plc": {"enabled": False},
        "devices": {"laser": {"kind": "sim"}, "robot": {"kind": "sim"}},
        "calibration.procedure.verify": {"laser_stands": 4, "views": 6, "keep_datasets": 2}}  # fmt: skip


def _os_bytes(folder: Path) -> int:
    return sum(os.stat(p).st_size for p in folder.rglob("*") if p.is_file())


def _set_datasets(store: Path) -> list[dict[str, Any]]:
    """Every dataset reference in every version of the set, read with json."""
    out: list[dict[str, Any]] = []
    for f in sorted(store.glob("set-*.json")):
        doc = json.loads(f.read_text())
        for section in [doc["parts"], *doc.get("recipes", {}).values()]:
            out += [p["dataset"] for p in section.values() if isinstance(p, dict) and p.get("dataset")]
    return out


async def _job(client: Any, procedure: str) -> dict[str, Any]:
    r = await client.post("/jobs", json={"procedure": procedure}, headers=AUTH)
    assert r.status_code == 201, r.text
    return await job_ended(client, r.json()["id"])


async def test_three_checks_leave_the_two_newest_and_every_dataset_the_set_names(tmp_path: Path) -> None:
    store = tmp_path / "var" / "calibration"  # calibration.directory of config/sim.toml, under the workdir
    folder = store / "datasets"
    async with running_service(tmp_path, sim_config(**CELL)) as service, api_client(service) as client:
        assert (await client.post("/commands/clear", headers=AUTH)).status_code == 200
        await asyncio.sleep(0.1)
        for procedure in ("camera", "hand_eye", "laser"):
            assert (await _job(client, procedure))["state"] == "done"
        checks, sizes = [], []
        for _ in range(3):
            job = await _job(client, "verify")
            assert job["state"] == "done" and job["result"]["quality"]["passed"], job
            checks.append(job)
            sizes.append(_os_bytes(Path(job["dataset"])) if Path(job["dataset"]).is_dir() else None)
    names = [Path(j["dataset"]).name for j in checks]
    left = sorted(n for n in os.listdir(folder) if n.startswith("verify-"))
    assert left == sorted(names[1:]), f"check datasets left: {left}; the checks wrote {names}"
    # Every dataset any version of the set names is there, its manifest as the set recorded it.
    refs = _set_datasets(store)
    assert {r["kind"] for r in refs} == {"board_views", "laser_plane"}
    for r in refs:
        assert hashlib.sha256((store / r["path"] / "manifest.json").read_bytes()).hexdigest() == r["manifest_sha256"], r
    # The jobs say what they removed, and the folder's size as the file system counts it.
    first, second, third = (j["result"]["quality"]["datasets"] for j in checks)
    assert first["pruned"] == [] and second["pruned"] == [] and second["kept"] == 2
    assert third["pruned"] == [names[0]] and third["kept"] == 2 and third["keep"] == 2
    assert sizes[0] and third["freed_mb"] == pytest.approx(sizes[0] / MIB, abs=1e-3)
    assert third["folder_mb"] == pytest.approx(_os_bytes(folder) / MIB, abs=1e-3)
