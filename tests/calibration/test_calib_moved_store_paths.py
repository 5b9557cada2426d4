"""The calibration store names its datasets relative to itself, and finds them after it moved to another folder.

A part recorded from a dataset in the store names it ``datasets/<name>``; one recorded by an earlier release names its
absolute path, read as stored while it is there and from ``<store>/datasets/<name>`` once the store has moved. Drift
check retention still keeps every dataset a set names, and the readiness hint for a stale part names the folder where
the dataset is now. Peers: ``json`` and ``hashlib`` on the files, the file system.
"""

from __future__ import annotations

import hashlib
import json
import shlex
import shutil
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
from calib_test_support import VALUES, config

from cellctl.calibration.calibration_set import CalibrationStore, make_part
from cellctl.calibration.compute import Outcome
from cellctl.calibration.dataset import default_dataset_dir, write_dataset
from cellctl.calibration.dataset_retention import prune_check_datasets
from cellctl.calibration.readiness import check_ready
from cellctl.calibration.recording import record

NOW = datetime(2026, 1, 15, 12, 0, tzinfo=timezone.utc)
RNG = np.random.default_rng(7)


def _images(n: int) -> dict[str, np.ndarray]:
    return {f"view_{i:03d}.png": RNG.integers(0, 255, (64, 64), dtype=np.uint8) for i in range(n)}


def _stale_hand_eye(root: Path, *, absolute: bool) -> tuple[CalibrationStore, Path]:
    """A store whose hand-eye (from a board-views dataset in the store, named by its absolute path if ``absolute``, as
    an earlier release did) was computed with a camera since replaced: (the store, the dataset's folder)."""
    store = CalibrationStore(root)
    views = write_dataset(default_dataset_dir(root, "board_views", NOW), "board_views", {"views": []}, _images(2))
    camera = make_part("camera", values=VALUES["camera"], method="test", when=NOW, valid_days=90.0)
    store.commit("camera", camera, now=NOW)
    if absolute:  # as an earlier release recorded it: the dataset's own reference, its absolute path
        hand_eye = make_part("hand_eye", values=VALUES["hand_eye"], method="test", when=NOW, valid_days=90.0,
                             inputs={"camera": camera.id}, dataset=views.ref({"kind": "board_views"}))  # fmt: skip
        store.commit("hand_eye", hand_eye, now=NOW)
    else:  # as a job (or the offline CLI) records it now
        record(store, Outcome("hand_eye", "test", VALUES["hand_eye"], {}, inputs={"camera": camera.id}), views, config(), NOW)
    later = NOW + timedelta(hours=1)
    store.commit("camera", make_part("camera", values=VALUES["camera"], method="again", when=later, valid_days=90.0), now=later)
    return store, views.root


def _hint_folder(store: CalibrationStore) -> Path:
    (hint,) = [p for p in check_ready(store.current(), NOW + timedelta(hours=2), store_root=store.root) if "--dataset" in p]
    return Path(shlex.split(hint[hint.index("`cellctl calibrate hand-eye --dataset"): hint.rindex("`")].strip("`"))[-1])


def _path_in_set(store: CalibrationStore) -> str:
    doc = json.loads((store.root / (store.root / "current").read_text().strip()).read_text())
    return str(doc["parts"]["hand_eye"]["dataset"]["path"])


def test_a_part_names_its_dataset_in_the_store_relative_to_it_and_the_hint_names_it_after_a_move(tmp_path: Path) -> None:
    store, folder = _stale_hand_eye(tmp_path / "pc1", absolute=False)
    assert _path_in_set(store) == f"datasets/{folder.name}"
    shutil.copytree(tmp_path / "pc1", tmp_path / "pc2")
    shutil.rmtree(tmp_path / "pc1")
    moved = CalibrationStore(tmp_path / "pc2")
    assert _hint_folder(moved) == tmp_path / "pc2" / "datasets" / folder.name
    assert (_hint_folder(moved) / "manifest.json").is_file()


def test_an_absolute_path_an_earlier_release_wrote_is_read_in_place_and_from_the_moved_stores_datasets(tmp_path: Path) -> None:
    store, folder = _stale_hand_eye(tmp_path / "pc1", absolute=True)
    assert _path_in_set(store) == str(folder) and Path(_path_in_set(store)).is_absolute()
    assert _hint_folder(store) == folder  # in place: as stored
    shutil.copytree(tmp_path / "pc1", tmp_path / "pc2")
    shutil.rmtree(tmp_path / "pc1")
    moved = CalibrationStore(tmp_path / "pc2")
    found = _hint_folder(moved)
    assert found == tmp_path / "pc2" / "datasets" / folder.name and found.is_dir()
    part = moved.current().part("hand_eye")  # type: ignore[union-attr]
    assert part is not None and part.dataset is not None
    assert hashlib.sha256((found / "manifest.json").read_bytes()).hexdigest() == part.dataset.manifest_sha256
    shutil.rmtree(found)  # gone from both places: the hint names it as the set does
    assert _hint_folder(moved) == folder


def test_check_datasets_a_set_names_relatively_are_kept(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path)
    named = write_dataset(default_dataset_dir(tmp_path, "verify", NOW - timedelta(days=3)), "verify", {"views": []}, _images(1))
    record(store, Outcome("camera", "test", VALUES["camera"], {}), named, config(), NOW)  # a set may name any kind
    assert _camera_path(tmp_path) == f"datasets/{named.root.name}"
    checks = [write_dataset(default_dataset_dir(tmp_path, "verify", NOW + timedelta(hours=h)), "verify", {"views": []},
                            _images(1)).root for h in (1, 2, 3)]  # fmt: skip
    report = prune_check_datasets(tmp_path, 1, just_written=checks[-1])
    assert named.root.is_dir() and checks[-1].is_dir() and not checks[0].exists() and not checks[1].exists()
    assert report.pruned == [checks[0].name, checks[1].name]


def _camera_path(root: Path) -> str:
    doc = json.loads((root / (root / "current").read_text().strip()).read_text())
    return str(doc["parts"]["camera"]["dataset"]["path"])
