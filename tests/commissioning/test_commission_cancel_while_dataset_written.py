"""A cancel that lands while a job writes its complete dataset: the record and the folder on disk agree.

The dataset being written is finished (one writer, into a hidden folder renamed into place); the job still ends
cancelled, its row (read with sqlite3) names that folder and says it is complete, and no second, partial copy is
written beside it. Scored on the files (manifest.json read with json) and the database row.
"""

from __future__ import annotations

import asyncio
import json
import sqlite3
import threading
import time
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from service_test_support import AUTH, api_client, running_service
from test_commission_jobs import _command, _config, _start, _wait_done

import cellctl.calibration.dataset as dsmod
import cellctl.commissioning.context as ctxmod
from cellctl.calibration.dataset import DatasetError, read_dataset, write_dataset

pytestmark = [pytest.mark.timeout(200)]


@pytest.mark.asyncio
async def test_a_cancel_while_the_complete_dataset_is_written_leaves_record_and_folder_agreeing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    writing = threading.Event()
    local = threading.local()
    real_cv2, write = dsmod.cv2, ctxmod.write_dataset
    writers: list[bool] = []

    def slow_encode(ext: str, img: object) -> object:
        if getattr(local, "complete", False):  # the complete dataset's images: large PNGs on a slow disk
            writing.set()
            time.sleep(0.1)
        return real_cv2.imencode(ext, img)

    def tracked_write(dest: Path, kind: str, manifest: dict[str, Any], images: dict[str, Any]) -> Any:
        local.complete = not manifest.get("partial")
        writers.append(local.complete)
        try:
            return write(dest, kind, manifest, images)
        finally:
            local.complete = False

    monkeypatch.setattr(dsmod, "cv2", types.SimpleNamespace(imencode=slow_encode, imdecode=real_cv2.imdecode,
                                                            IMREAD_UNCHANGED=real_cv2.IMREAD_UNCHANGED))  # fmt: skip
    monkeypatch.setattr(ctxmod, "write_dataset", tracked_write)
    async with running_service(tmp_path, _config(answers="all")) as service, api_client(service) as client:
        await _command(client, "clear")
        job = await _start(client, "camera")
        while not writing.is_set():
            await asyncio.sleep(0.005)
        assert (await client.post(f"/jobs/{job['id']}/cancel", headers=AUTH)).status_code == 200
        done = await _wait_done(client, job["id"])
    datasets = tmp_path / "var" / "calibration" / "datasets"
    assert writers == [True], writers  # one writer: no partial copy raced the complete one
    assert [f.name for f in datasets.iterdir()] == [Path(done["dataset"]).name]  # nothing half-written left beside it
    manifest = json.loads((Path(done["dataset"]) / "manifest.json").read_text())
    assert "partial" not in manifest and len(manifest["views"]) == 12, manifest.keys()
    assert read_dataset(done["dataset"], "board_views").manifest["views"] == manifest["views"]  # complete and usable
    db_path = tmp_path / "var" / "cellctl.db"
    assert db_path.exists()
    db = sqlite3.connect(db_path)
    state, error, dataset = db.execute("SELECT state, error, dataset FROM jobs WHERE id = ?", (job["id"],)).fetchone()
    db.close()
    assert (state, dataset) == ("cancelled", done["dataset"])
    assert error.startswith("cancelled by") and "complete dataset" in error and "kept" in error, error


def test_a_dataset_folder_is_whole_or_absent_and_a_second_writer_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    img = np.full((8, 8), 7, np.uint8)
    root = tmp_path / "datasets" / "board_views-x"
    real = dsmod.cv2.imencode
    calls = {"n": 0}

    def failing(ext: str, a: object) -> object:
        calls["n"] += 1
        if calls["n"] == 2:
            raise OSError(28, "No space left on device")
        return real(ext, a)

    monkeypatch.setattr(dsmod.cv2, "imencode", failing)
    with pytest.raises(OSError):
        write_dataset(root, "board_views", {"views": []}, {"a.png": img, "b.png": img})
    assert not root.exists() and list(root.parent.iterdir()) == []  # no half a dataset, no leftovers
    monkeypatch.setattr(dsmod.cv2, "imencode", real)
    first = write_dataset(root, "board_views", {"views": ["a"]}, {"a.png": img})
    with pytest.raises(DatasetError, match="not empty"):
        write_dataset(root, "board_views", {"views": ["b"], "partial": True}, {"b.png": img})
    on_disk = json.loads((root / "manifest.json").read_text())
    assert on_disk == first.manifest and sorted(p.name for p in root.iterdir()) == ["a.png", "manifest.json"]
    assert [p.name for p in root.parent.iterdir()] == [root.name]
