"""A calibration store moved to another folder (a new PC, a backup restored elsewhere) keeps its drift check.

The set names each part's dataset relative to the store (``datasets/<name>``), and a set file an earlier release wrote
with absolute paths is read in place and, once the store has moved, from ``<store>/datasets/<name>``. The cell is the
seeded twin, calibrated by the service's own procedures (:class:`TwinCommissioning`) into a store under ``pc1``; the
store is copied to ``pc2`` and ``pc1`` removed. Peers: the twin's truth (its camera knocked on the flange), ``json`` and
``hashlib`` on the set files and the dataset manifests, the file system.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import hashlib
import json
import shutil
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from shared_support import scratch_dir
from service_test_support import AUTH, api_client, running_service, sim_config

from cellctl.calibration.calibration_set import CalibrationStore
from cellctl.calibration.dataset import Dataset, default_dataset_dir
from cellctl.calibration.readiness import check_ready
from cellctl.calibration.recording import record
from cellctl.cli import DEFAULT_CONFIG, main
from cellctl.commissioning.registry import ALL_PROCEDURES
from cellctl.geometry.pose import make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix
from cellctl.sim.commissioning import TwinCommissioning

SEED = 11
CELL = {"calibration": {"source": "set", "auto_calibrate_in_sim": False}, "plc": {"enabled": False},
        "devices": {"laser": {"kind": "sim"}, "robot": {"kind": "sim"}},
        "calibration.procedure.verify": {"laser_stands": 4}}  # fmt: skip
STORE = Path("var") / "calibration"  # calibration.directory of config/sim.toml, under the workdir
KNOCK = make_pose(axis_angle_to_matrix(np.radians(0.05) * np.array([0.0, 0.6, 0.8])), [0.3, 0.0, 0.0])  # the camera on the flange


@functools.lru_cache(maxsize=1)
def _config() -> Any:
    return sim_config(**CELL)


@functools.lru_cache(maxsize=1)
def _commissioned() -> Path:
    """A workdir whose store holds camera, hand-eye and laser calibrated in the seeded twin from datasets in the store."""
    cfg = _config()
    workdir = scratch_dir("cellctl-moved-store") / "cell"
    store = CalibrationStore(workdir / STORE)

    async def go() -> None:
        twin = TwinCommissioning(cfg, seed=SEED)
        try:
            for part in ("camera", "hand_eye", "laser"):
                proc = ALL_PROCEDURES[part]
                ds = await twin.collect(part, store.current(), default_dataset_dir(store.root, proc.kind).with_name(f"{proc.kind}-{part}"))
                record(store, await asyncio.to_thread(proc.compute, ds, store.current(), cfg), ds, cfg, datetime.now(timezone.utc))
        finally:
            await twin.close()

    asyncio.run(go())
    return workdir


@pytest.fixture
def commissioned() -> Path:
    """:func:`_commissioned` (made outside the test's event loop: its twin runs one of its own)."""
    return _commissioned()


@contextlib.contextmanager
def _gone(folder: Path) -> Iterator[None]:
    """``folder`` is not there (the old PC is gone) while the block runs; put back after it, for the other tests."""
    aside = folder.with_name(folder.name + ".gone")
    folder.rename(aside)
    try:
        yield
    finally:
        aside.rename(folder)


def _old_format(commissioned: Path, tmp_path: Path) -> Path:
    """The commissioned workdir copied to ``pc1``, its set files naming each dataset by its absolute path there, as
    a release before relative paths wrote them."""
    pc1 = tmp_path / "pc1" / "cellctl"
    shutil.copytree(commissioned, pc1)
    for f in (pc1 / STORE).glob("set-*.json"):
        doc = json.loads(f.read_text())
        for part in doc["parts"].values():
            if part and part.get("dataset"):
                part["dataset"]["path"] = str(pc1 / STORE / "datasets" / Path(part["dataset"]["path"]).name)
        f.write_text(json.dumps(doc, indent=2))
    return pc1


def _relocate(pc1: Path, pc2: Path) -> None:
    pc2.parent.mkdir(parents=True)
    shutil.copytree(pc1, pc2, symlinks=True)
    shutil.rmtree(pc1)


def _sha(folder: Path) -> str:
    return hashlib.sha256((folder / "manifest.json").read_bytes()).hexdigest()


async def _plan(workdir: Path) -> dict[str, Any]:
    """The check's plan as the service on ``workdir`` answers ``POST /jobs/plan`` (nothing moves)."""
    async with running_service(workdir, _config()) as service, api_client(service) as client:
        r = await client.post("/jobs/plan", json={"procedure": "verify"}, headers=AUTH)
    assert r.status_code == 200, r.text
    return r.json()  # type: ignore[no-any-return]


async def _check(twin: TwinCommissioning, store: CalibrationStore, name: str) -> tuple[Dataset, dict[str, Any]]:
    """A drift check collected into the store (as a job writes it) and computed: (its dataset, the quality figures)."""
    ds = await twin.collect("verify", store.current(), default_dataset_dir(store.root, "verify").with_name(f"verify-{name}"))
    outcome = await asyncio.to_thread(ALL_PROCEDURES["verify"].compute, ds, store.current(), _config())
    return ds, outcome.quality


def test_a_moved_store_names_its_datasets_by_store_path_and_its_check_finds_the_twins_knocked_camera(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], commissioned: Path
) -> None:
    pc2 = tmp_path / "pc2" / "srv" / "cellctl"
    shutil.copytree(commissioned, pc2, symlinks=True)  # the data folder copied to the new PC's path
    with _gone(commissioned):
        _check_on_the_new_pc(pc2, capsys)


def _check_on_the_new_pc(pc2: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store = CalibrationStore(pc2 / STORE)
    plan = asyncio.run(_plan(pc2))  # the service on the new PC plans the check
    assert plan["details"]["board_datasets"] == {"hand_eye": "datasets/board_views-hand_eye", "camera": "datasets/board_views-camera"}
    assert plan["details"]["laser_dataset"] == "datasets/laser_plane-laser"
    # Every part names its dataset inside the store, and that folder holds the manifest the part recorded.
    refs = [p["dataset"] for f in sorted(store.root.glob("set-*.json")) for p in json.loads(f.read_text())["parts"].values() if p]
    assert refs and all(r["path"].startswith("datasets/") and not Path(r["path"]).is_absolute() for r in refs), refs
    assert all(_sha(store.root / r["path"]) == r["manifest_sha256"] for r in refs)

    async def go() -> tuple[dict[str, Any], dict[str, Any], Dataset]:
        twin = TwinCommissioning(_config(), seed=SEED)  # the same cell, its data folder on another PC
        try:
            ds, still = await _check(twin, store, "unchanged")
            twin.cell.T_H_C = twin.cell.T_H_C @ KNOCK  # the truth: the camera knocked 0.3 mm / 0.05 deg on the flange
            _, knocked = await _check(twin, store, "knocked")
            return still, knocked, ds
        finally:
            await twin.close()

    still, knocked, ds = asyncio.run(go())
    assert still["passed"], still
    assert still["hand_eye"]["translation_mm"] < 0.25 and still["hand_eye"]["rotation_deg"] < 0.025
    assert still["laser"]["readings"] >= 40
    assert not knocked["passed"] and knocked["hand_eye"]["rotation_deg"] > 0.025, knocked
    assert "cellctl calibrate hand-eye" in " ".join(knocked["beyond_limits"])
    assert ds.manifest["reference"]["laser_dataset"] == "datasets/laser_plane-laser"  # the check names them in the store too
    # The check recomputed offline on the new PC from its dataset: it reads the references where the store is now.
    capsys.readouterr()
    rc = main(["--config", str(DEFAULT_CONFIG), "calibrate", "verify", "--workdir", str(pc2), "--dataset", str(ds.root)])
    out = capsys.readouterr()
    assert rc == 0 and "cannot be read" not in out.out + out.err, out.out + out.err


async def test_a_set_file_an_earlier_release_wrote_with_absolute_paths_works_in_place_and_after_the_move(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], commissioned: Path
) -> None:
    pc1, pc2 = _old_format(commissioned, tmp_path), tmp_path / "pc2" / "srv" / "cellctl"
    where = {name: str(pc1 / STORE / "datasets" / f"{kind}-{name}")
             for name, kind in (("camera", "board_views"), ("hand_eye", "board_views"), ("laser", "laser_plane"))}  # fmt: skip
    on_disk = json.loads((pc1 / STORE / "set-000003.json").read_text())["parts"]
    assert {n: on_disk[n]["dataset"]["path"] for n in where} == where  # as the earlier release wrote them
    in_place = (await _plan(pc1))["details"]  # the check plans where the set was written
    assert {k: Path(v).name for k, v in in_place["board_datasets"].items()} == {"hand_eye": "board_views-hand_eye",
                                                                                "camera": "board_views-camera"}
    _relocate(pc1, pc2)
    assert not Path(where["hand_eye"]).exists()
    # The service on the new PC plans the check (it was refused: "the hand_eye calibration's dataset cannot be read").
    moved = await _plan(pc2)
    assert moved["details"]["laser_dataset"] == "datasets/laser_plane-laser" and moved["poses"] > 0, moved
    # A stale hand-eye: the hint names its dataset where it is now, and that command recomputes it.
    store = CalibrationStore(pc2 / STORE)
    cal = store.current()
    assert cal is not None and cal.part("camera") is not None
    store.commit("camera", cal.part("camera").model_copy(update={"id": "camera-recalibrated"}))  # type: ignore[union-attr]
    (hint,) = [p for p in check_ready(store.current(), datetime.now(timezone.utc), store_root=store.root) if "--dataset" in p]
    command = hint[hint.index("`cellctl calibrate hand-eye --dataset ") + 1: hint.rindex("`")]
    assert command == f"cellctl calibrate hand-eye --dataset {pc2 / STORE / 'datasets' / 'board_views-hand_eye'}", hint
    capsys.readouterr()
    rc = main(["--config", str(DEFAULT_CONFIG), *command.split()[1:], "--workdir", str(pc2)])
    out = capsys.readouterr().out
    assert rc == 0 and "computed with camera camera-recalibrated" in out and "stored as version 5" in out, out
    written = json.loads((store.root / "set-000005.json").read_text())
    recomputed = written["parts"]["hand_eye"]
    assert recomputed["dataset"] == {**on_disk["hand_eye"]["dataset"], "path": "datasets/board_views-hand_eye"}
    assert written["written_by"]["dataset"] == "datasets/board_views-hand_eye"
    assert written["written_by"]["dataset_manifest_sha256"] == _sha(Path(command.split()[-1]))
    # the same views and the same camera values: the same hand-eye
    assert np.allclose(recomputed["values"]["T_H_C"], on_disk["hand_eye"]["values"]["T_H_C"], atol=1e-9)
