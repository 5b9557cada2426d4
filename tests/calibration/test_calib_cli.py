"""``cellctl calibrate ... --dataset``: offline recomputation, refusals that change nothing, status.

(The commands that run on the cell talk to the service: tests/commissioning covers them.)
"""

from __future__ import annotations

import asyncio
import functools
from pathlib import Path

import pytest
from calib_test_support import config, scratch

from cellctl.calibration.calibration_set import CalibrationStore
from cellctl.calibration.dataset import Dataset, read_dataset, write_dataset
from cellctl.cli import DEFAULT_CONFIG, main
from cellctl.sim.commissioning import TwinCommissioning


def _run(*args: str) -> int:
    return main(["--config", str(DEFAULT_CONFIG), *args])


@functools.lru_cache(maxsize=1)
def _laser_dataset() -> Dataset:
    async def go() -> Dataset:
        twin = TwinCommissioning(config(), seed=4)
        try:
            return await twin.collect("laser", None, scratch("cli-laser") / "ds", poses=120)
        finally:
            await twin.close()

    return asyncio.run(go())


def test_a_saved_laser_dataset_is_computed_offline_and_stored(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store_dir = tmp_path / "store"
    ds = _laser_dataset()
    assert _run("calibrate", "laser", "--store", str(store_dir), "--dataset", str(ds.root)) == 0
    out = capsys.readouterr().out
    assert "computing offline" in out and "true error: r" in out and "stored as version 1" in out
    store = CalibrationStore(store_dir)
    first = store.current()
    assert first is not None and first.part("laser").status == "ok"
    ref = first.part("laser").dataset
    assert ref is not None and ref.kind == "laser_plane" and ref.path == str(ds.root)
    # The same data again: the same result, identical to the laser in use, so no new version (its new id would make
    # every part computed with it stale); tests/calibration/test_calib_recompute_dataset.py covers the dependents.
    capsys.readouterr()
    assert _run("calibrate", "laser", "--store", str(store_dir), "--dataset", ref.path) == 0
    assert f"identical to the laser in use ({first.part('laser').id}); not stored" in capsys.readouterr().out
    assert store.current() == first and store.versions() == [1]
    # Not ready: the other parts are missing, and status says so.
    assert _run("calibrate", "status", "--store", str(store_dir), "--history") == 1
    out = capsys.readouterr().out
    assert "camera: missing; run `cellctl calibrate camera`" in out and "v1" in out


def test_a_refusal_is_printed_and_the_set_in_use_stays_as_it_was(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store_dir = tmp_path / "store"
    ds = _laser_dataset()
    assert _run("calibrate", "laser", "--store", str(store_dir), "--dataset", str(ds.root)) == 0
    manifest = {k: v for k, v in ds.manifest.items() if k not in ("format", "kind", "files", "written_utc")}
    manifest["readings"] = manifest["readings"][:20]
    write_dataset(tmp_path / "short", "laser_plane", manifest, {})
    capsys.readouterr()
    assert _run("calibrate", "laser", "--store", str(store_dir), "--dataset", str(tmp_path / "short")) == 1
    out = capsys.readouterr().out
    assert "REFUSED (too_few_poses)" in out and "unchanged" in out
    cal = CalibrationStore(store_dir).current()
    assert cal.version == 1 and cal.part("laser").status == "ok"


def test_a_partial_dataset_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ds = _laser_dataset()
    manifest = {k: v for k, v in ds.manifest.items() if k not in ("format", "kind", "files", "written_utc")}
    write_dataset(tmp_path / "partial", "laser_plane", {**manifest, "partial": True, "ended": "cancelled by operator"}, {})
    assert _run("calibrate", "laser", "--store", str(tmp_path / "s"), "--dataset", str(tmp_path / "partial")) == 2
    assert "a partial dataset (cancelled by operator)" in capsys.readouterr().err
    assert read_dataset(tmp_path / "partial", "laser_plane", allow_partial=True).manifest["partial"] is True


def test_parts_that_need_others_say_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_dataset(tmp_path / "teach", "teaching", {}, {})
    assert _run("teach", "--store", str(tmp_path / "s"), "--dataset", str(tmp_path / "teach"), "--no-store") == 1
    out = capsys.readouterr().out
    assert "REFUSED (missing_input)" in out and "camera is not calibrated yet" in out


def test_a_dataset_of_the_wrong_kind_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_dataset(tmp_path / "d", "teaching", {}, {})
    assert _run("calibrate", "laser", "--store", str(tmp_path / "s"), "--dataset", str(tmp_path / "d")) == 2
    assert "needs a 'laser_plane' dataset" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()  # nothing recorded for a usage error


def test_without_a_running_service_the_command_says_where_it_looked(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run("calibrate", "laser", "--url", "http://127.0.0.1:9", "--dry-run") == 1
    err = capsys.readouterr().err
    assert "cannot reach the cell service at http://127.0.0.1:9" in err and "cellctl serve" in err


def test_a_dataset_another_cell_recorded_is_refused_unless_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Its poses and readings are that cell's: stored here, the beam would be the other laser's. The manifest's source
    names the cell (cell_id) and mode that recorded it; config/sim.toml is cell-1 in mode sim."""
    store_dir, ds = tmp_path / "store", _laser_dataset()
    manifest = {k: v for k, v in ds.manifest.items() if k not in ("format", "kind", "files", "written_utc")}
    for name, source in (("cell2", {**manifest["source"], "cell": "cell-2"}), ("real", {**manifest["source"], "mode": "hardware"})):
        write_dataset(tmp_path / name, "laser_plane", {**manifest, "source": source}, {})
    capsys.readouterr()
    assert _run("calibrate", "laser", "--store", str(store_dir), "--dataset", str(tmp_path / "cell2")) == 2
    err = capsys.readouterr().err
    assert "recorded on cell 'cell-2', this configuration is cell_id 'cell-1'" in err and "--accept-cell cell-2" in err, err
    assert _run("calibrate", "laser", "--store", str(store_dir), "--dataset", str(tmp_path / "real")) == 2
    assert "recorded in mode 'hardware'" in capsys.readouterr().err
    assert CalibrationStore(store_dir).versions() == []  # nothing stored
    assert _run("calibrate", "laser", "--store", str(store_dir), "--dataset", str(tmp_path / "cell2"), "--accept-cell", "cell-2") == 0
    assert CalibrationStore(store_dir).versions() == [1]
