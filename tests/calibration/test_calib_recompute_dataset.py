"""``cellctl calibrate ... --dataset`` on the dataset a part in use came from, and after the part it builds on changed.

Recomputing the very dataset of the part in use gives the same values (a new id would make every part computed with it
stale and stop production): nothing is stored. A part that does change names, for each part it makes stale, the offline
way beside the job. A hand-eye recomputed after a camera recalibration says which camera it used and which one the
dataset's hand-eye was computed with. The data: the seeded twin's board views (calib_test_support), camera and hand-eye
computed from them; the peers: the store folder's files as the OS lists and json reads them.
"""

from __future__ import annotations

import functools
import json
import shutil
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from calib_test_support import NOW, board_views, config, scratch, store_with_camera

from cellctl.calibration.calibration_set import CalibrationStore
from cellctl.calibration.compute import Outcome, compute_hand_eye
from cellctl.calibration.dataset import Dataset, write_dataset
from cellctl.calibration.readiness import check_ready
from cellctl.calibration.recording import record
from cellctl.cli import DEFAULT_CONFIG, main


def _run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str]:
    capsys.readouterr()
    rc = main(["--config", str(DEFAULT_CONFIG), *args])
    return rc, capsys.readouterr().out


@functools.lru_cache(maxsize=1)
def _hand_eye() -> Outcome:
    ds, dets = board_views()
    return compute_hand_eye(ds, store_with_camera().current(), config(), dets)


def _commissioned(root: Path) -> CalibrationStore:
    """A store in root holding the camera and the hand-eye computed with it, both from the twin's board views."""
    ds, _ = board_views()
    shutil.copytree(store_with_camera().root, root)
    store = CalibrationStore(root)
    assert _hand_eye().inputs == {"camera": store.current().part("camera").id}  # type: ignore[union-attr]
    record(store, _hand_eye(), ds, config(), NOW)
    return store


@functools.lru_cache(maxsize=1)
def _fewer_views() -> Dataset:
    """The same views but the last: another camera dataset, so another lens."""
    ds, _ = board_views()
    keep = ds.manifest["views"][:-1]
    manifest = {k: v for k, v in ds.manifest.items() if k not in ("format", "kind", "written_utc", "files", "views")}
    return write_dataset(scratch("fewer") / "ds", "board_views", {**manifest, "views": keep},
                         {v["image"]: ds.image(v["image"]) for v in keep})  # fmt: skip


def _files(root: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(root.iterdir()) if p.is_file()}


def _set(root: Path) -> dict[str, Any]:
    """The set in use as json reads it from the files the pointer names."""
    return json.loads((root / (root / "current").read_text().strip()).read_text())  # type: ignore[no-any-return]


def test_recomputing_the_dataset_of_the_part_in_use_stores_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store = _commissioned(tmp_path / "store")
    ds, _ = board_views()
    before = _files(store.root)
    camera_id, hand_eye_id = _set(store.root)["parts"]["camera"]["id"], _set(store.root)["parts"]["hand_eye"]["id"]
    copy = shutil.copytree(ds.root, tmp_path / "moved")  # the same dataset, moved: known by its content
    for folder in (ds.root, copy):
        rc, out = _run(capsys, "calibrate", "camera", "--store", str(store.root), "--dataset", str(folder))
        assert rc == 0, out
        assert f"identical to the camera in use ({camera_id}); not stored" in out, out
    rc, out = _run(capsys, "calibrate", "hand-eye", "--store", str(store.root), "--dataset", str(ds.root))
    assert rc == 0, out
    assert f"computed with camera {camera_id} (the set in use)" in out and "note:" not in out, out
    assert f"identical to the hand_eye in use ({hand_eye_id}); not stored" in out, out
    assert _files(store.root) == before  # no new version, the pointer as it was
    assert check_ready(store.current(), NOW + timedelta(hours=1)) == [
        f"{p}: missing; run `cellctl {c}`" for p, c in
        (("laser", "calibrate laser"), ("teaching", "teach"), ("pixel_map", "calibrate nine-point"))
    ]  # fmt: skip


def test_a_new_camera_offers_recomputing_the_hand_eye_dataset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store = _commissioned(tmp_path / "store")
    ds, _ = board_views()
    rc, out = _run(capsys, "calibrate", "camera", "--store", str(store.root), "--dataset", str(_fewer_views().root))
    assert rc == 0 and "stored as version 3" in out, out
    cal = _set(store.root)
    old_camera = cal["parts"]["hand_eye"]["inputs"]["camera"]
    new_camera = cal["parts"]["camera"]["id"]
    assert old_camera != new_camera
    assert (f"hand_eye: computed with camera {old_camera}, but the set now holds camera {new_camera}; run "
            "`cellctl calibrate hand-eye` again, or, if nothing was touched since its dataset was recorded, recompute that "
            f"dataset offline once the parts it is computed with are current: `cellctl calibrate hand-eye --dataset {ds.root}`"
            ) in out, out  # fmt: skip
    # The offline way, as offered: the hand-eye of the new camera, and the set ready again as far as these parts go.
    rc, out = _run(capsys, "calibrate", "hand-eye", "--store", str(store.root), "--dataset", str(ds.root))
    assert rc == 0 and "stored as version 4" in out, out
    assert _set(store.root)["parts"]["hand_eye"]["inputs"] == {"camera": new_camera}
    assert not [p for p in check_ready(store.current(), datetime.now(timezone.utc)) if "computed with" in p]


def test_a_hand_eye_recompute_names_the_camera_it_used_and_the_one_of_before(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store = _commissioned(tmp_path / "store")
    ds, _ = board_views()
    job_t = np.asarray(_set(store.root)["parts"]["hand_eye"]["values"]["T_H_C"])[:3, 3]
    assert _run(capsys, "calibrate", "camera", "--store", str(store.root), "--dataset", str(_fewer_views().root))[0] == 0
    cal = _set(store.root)
    old_camera, new_camera, hand_eye_id = cal["parts"]["hand_eye"]["inputs"]["camera"], cal["parts"]["camera"]["id"], cal["parts"]["hand_eye"]["id"]
    before = _files(store.root)
    rc, out = _run(capsys, "calibrate", "hand-eye", "--store", str(store.root), "--dataset", str(ds.root), "--no-store")
    assert rc == 0, out
    assert f"computed with camera {new_camera} (the set in use)" in out, out
    assert (f"note: this dataset gave hand_eye {hand_eye_id}, computed with camera {old_camera}; this result is computed with "
            f"camera {new_camera} instead") in out, out  # fmt: skip
    assert _files(store.root) == before
    # and the result does differ from the dataset's first hand-eye, by the camera alone (the printed translation)
    line = next(ln for ln in out.splitlines() if "T_H_C translation (" in ln)
    t = np.array([float(x) for x in line.split("(", 1)[1].split(")", 1)[0].split(",")])
    assert 1e-4 < np.linalg.norm(t - job_t) < 1.0
