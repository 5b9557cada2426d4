"""``cellctl calibrate ...``: on the simulated cell, offline from a dataset, refusals recorded, status."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.calibration.calibration_set import CalibrationStore, check_ready
from cellctl.calibration.dataset import read_dataset, write_dataset
from cellctl.cli import DEFAULT_CONFIG, main


def _run(*args: str) -> int:
    return main(["--config", str(DEFAULT_CONFIG), *args])


def test_laser_on_the_twin_then_again_offline_from_its_dataset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store_dir = tmp_path / "store"
    assert _run("calibrate", "laser", "--store", str(store_dir), "--seed", "4") == 0
    out = capsys.readouterr().out
    assert "collecting on the simulated cell" in out and "true error: r" in out and "stored as version 1" in out
    store = CalibrationStore(store_dir)
    first = store.current()
    assert first is not None and first.part("laser").status == "ok"
    ref = first.part("laser").dataset
    assert ref is not None and ref.kind == "laser_plane"
    # Recompute from the saved folder: same data, same result; a new version in the history.
    assert _run("calibrate", "laser", "--store", str(store_dir), "--dataset", ref.path) == 0
    second = store.current()
    assert second.version == 2 and second.parent_version == 1
    assert second.part("laser").values == first.part("laser").values
    assert second.part("laser").dataset.manifest_sha256 == ref.manifest_sha256
    # Not ready: the other parts are missing, and status says so.
    assert _run("calibrate", "status", "--store", str(store_dir), "--history") == 1
    out = capsys.readouterr().out
    assert "camera: missing; run `cellctl calibrate camera`" in out and "v2" in out


def test_a_refusal_is_printed_and_recorded_as_failed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store_dir = tmp_path / "store"
    assert _run("calibrate", "laser", "--store", str(store_dir), "--seed", "4", "--save-dataset", str(tmp_path / "full")) == 0
    ds = read_dataset(tmp_path / "full", "laser_plane")
    manifest = {k: v for k, v in ds.manifest.items() if k not in ("format", "kind", "files", "written_utc")}
    manifest["readings"] = manifest["readings"][:20]
    write_dataset(tmp_path / "short", "laser_plane", manifest, {})
    capsys.readouterr()
    assert _run("calibrate", "laser", "--store", str(store_dir), "--dataset", str(tmp_path / "short")) == 1
    out = capsys.readouterr().out
    assert "REFUSED (too_few_poses)" in out and "recorded as failed" in out
    cal = CalibrationStore(store_dir).current()
    assert cal.part("laser").status == "failed"
    assert any(p.startswith("laser: the last calibration failed") for p in check_ready(cal, cal.created_utc))


def test_parts_that_need_others_say_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run("calibrate", "hand-eye", "--store", str(tmp_path / "s"), "--no-store") == 1
    assert "camera must be calibrated first" in capsys.readouterr().out
    assert _run("teach", "--store", str(tmp_path / "s"), "--no-store") == 1
    assert "must be calibrated first" in capsys.readouterr().out


def test_a_dataset_of_the_wrong_kind_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_dataset(tmp_path / "d", "teaching", {}, {})
    assert _run("calibrate", "laser", "--store", str(tmp_path / "s"), "--dataset", str(tmp_path / "d")) == 2
    assert "needs a 'laser_plane' dataset" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()  # nothing recorded for a usage error


def test_workdir_puts_the_store_where_the_service_reads_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from cellctl.calibration.source import CalibrationSetSource
    from cellctl.config import load_config

    work = tmp_path / "cell"
    assert _run("calibrate", "laser", "--workdir", str(work), "--seed", "4", "--poses", "120") == 0
    config = load_config(DEFAULT_CONFIG)
    service_store = CalibrationSetSource.from_config(config, workdir=work).store
    cal = service_store.current()
    assert cal is not None and cal.part("laser").status == "ok"
    assert str(work / config.calibration.directory) in capsys.readouterr().out
    assert _run("calibrate", "status", "--workdir", str(work)) == 1  # found, and not ready: parts missing
    assert "1 version(s), current 1" in capsys.readouterr().out
