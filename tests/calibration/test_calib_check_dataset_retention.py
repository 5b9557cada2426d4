"""The drift checks' datasets are bounded: the newest ``keep_datasets`` and every dataset a set version names stay.

Peers: the file system (listing and sizes from os.stat) and the set files read with json.
"""

from __future__ import annotations

import hashlib
import json
import os
from datetime import timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from calib_test_support import NOW, VALUES

from cellctl.calibration.calibration_set import CalibrationStore, make_part
from cellctl.calibration.dataset import default_dataset_dir, write_dataset
from cellctl.calibration.dataset_retention import prune_check_datasets
from cellctl.config.calibration_procedure import VerifyCalibrationConfig

MIB = 1024**2
RNG = np.random.default_rng(3)


def _images(n: int) -> dict[str, np.ndarray]:
    return {f"view_{i:03d}.png": RNG.integers(0, 255, (200, 200), dtype=np.uint8) for i in range(n)}  # ~40 kB each


def _os_bytes(folder: Path) -> int:
    return sum(os.stat(p).st_size for p in folder.rglob("*") if p.is_file())


def _named_in_sets(root: Path) -> list[dict[str, Any]]:
    """Every dataset reference ({kind, path, manifest_sha256}) in every set file, read with json."""
    out: list[dict[str, Any]] = []

    def walk(v: Any) -> None:
        if isinstance(v, dict):
            if isinstance(v.get("dataset"), dict):
                out.append(v["dataset"])
            for item in v.values():
                walk(item)
        elif isinstance(v, list):
            for item in v:
                walk(item)

    for f in sorted(root.glob("set-*.json")):
        walk(json.loads(f.read_text()))
    return out


def _store(root: Path) -> tuple[CalibrationStore, Path, Path]:
    """A store whose version 1 names a verify-kind dataset (its camera's, as an old version might) and whose version 2
    (in use) names a board-views dataset: (store, the verify dataset named by version 1, the board views)."""
    store = CalibrationStore(root)
    old = write_dataset(default_dataset_dir(root, "verify", NOW - timedelta(days=30)), "verify", {"views": []}, _images(2))
    views = write_dataset(default_dataset_dir(root, "board_views", NOW), "board_views", {"views": []}, _images(3))
    for k, ds in enumerate((old, views)):
        part = make_part("camera", values=VALUES["camera"], method="test", when=NOW + timedelta(hours=k), valid_days=90.0,
                         dataset=ds.ref())  # fmt: skip
        store.commit("camera", part, now=NOW + timedelta(hours=k))
    return store, old.root, views.root


def _checks(root: Path, hours: list[int]) -> list[Path]:
    return [write_dataset(default_dataset_dir(root, "verify", NOW + timedelta(hours=h)), "verify", {"views": []}, _images(4)).root
            for h in hours]  # fmt: skip


def test_only_the_newest_checks_stay_and_no_dataset_a_set_version_names_goes(tmp_path: Path) -> None:
    store, named_verify, views = _store(tmp_path)
    folder = tmp_path / "datasets"
    checks = _checks(tmp_path, [1, 2, 3, 4, 5])
    (folder / "verify-by-hand").mkdir()  # not a dataset the cell wrote (no manifest): never touched
    (folder / "verify-by-hand" / "notes.txt").write_text("keep me")
    (folder / ".verify-20250101T000000Z.pruning").mkdir()  # a pass that stopped mid-way: finished by this one
    before = {p.name: _os_bytes(p) for p in checks}

    report = prune_check_datasets(tmp_path, 2, just_written=checks[-1])

    left = sorted(os.listdir(folder))
    assert left == sorted([named_verify.name, views.name, checks[3].name, checks[4].name, "verify-by-hand"]), left
    assert report.pruned == [p.name for p in checks[:3]] and report.kept == 3 and report.keep == 2 and report.held is None
    assert report.freed_mb == pytest.approx(sum(before[p.name] for p in checks[:3]) / MIB, abs=1e-3)
    assert report.folder_mb == pytest.approx(_os_bytes(folder) / MIB, abs=1e-3)
    # Every dataset any version of the set names is still there, unchanged (the manifest's SHA-256 the set recorded).
    refs = _named_in_sets(tmp_path)
    assert {Path(r["path"]).name for r in refs} == {named_verify.name, views.name} and store.versions() == [1, 2]
    for r in refs:
        assert hashlib.sha256((Path(r["path"]) / "manifest.json").read_bytes()).hexdigest() == r["manifest_sha256"]
    assert not [n for n in os.listdir(folder) if n.startswith(".")]  # nothing left half removed


def test_the_check_just_written_stays_even_when_its_time_is_older_than_the_rest(tmp_path: Path) -> None:
    _store(tmp_path)
    checks = _checks(tmp_path, [1, 2, 3])
    stepped_back = _checks(tmp_path, [-5])[0]  # the clock was set back before this check
    report = prune_check_datasets(tmp_path, 1, just_written=stepped_back)
    left = {n for n in os.listdir(tmp_path / "datasets") if n.startswith("verify-")}
    assert stepped_back.name in left and stepped_back.name not in report.pruned
    assert {p.name for p in checks}.isdisjoint(left)


def test_nothing_goes_while_a_set_file_cannot_be_read(tmp_path: Path) -> None:
    _store(tmp_path)
    checks = _checks(tmp_path, [1, 2, 3])
    (tmp_path / "set-000003.json").write_text("{not json")  # what it names cannot be known
    report = prune_check_datasets(tmp_path, 1, just_written=checks[-1])
    assert all(p.is_dir() for p in checks) and report.pruned == []
    assert report.held and "set-000003.json" in report.held


def test_keep_datasets_defaults_to_ten_and_refuses_less_than_one() -> None:
    from cellctl.config import ConfigError
    from cellctl.config.loader import parse_config
    import tomllib

    root = Path(__file__).resolve().parents[2]
    data = tomllib.loads((root / "config" / "sim.toml").read_text())
    assert parse_config(data).calibration.procedure.verify.keep_datasets == 10 == VerifyCalibrationConfig().keep_datasets
    data["calibration"].setdefault("procedure", {}).setdefault("verify", {})["keep_datasets"] = 0
    with pytest.raises(ConfigError, match=r"calibration\.procedure\.verify: keep_datasets 0: give at least 1"):
        parse_config(data)
