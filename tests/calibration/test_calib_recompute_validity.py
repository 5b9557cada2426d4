"""An offline recompute counts as calibrated when its dataset was captured, not when it was computed.

A camera calibrated today from board views captured 120 days ago describes the lens as it was then: its validity
(``calibration.max_age_days``, 90 in config/sim.toml) has already run out, and the cell must say so rather than
count 90 days from today. The data: the seeded twin's board views (calib_test_support) with the capture time set
in their manifest; the peers: the manifest and the stored set as json reads them from the files.
"""

from __future__ import annotations

import json
import shutil
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import pytest
from calib_test_support import board_views, scratch

from cellctl.calibration.dataset import Dataset, write_dataset
from cellctl.cli import DEFAULT_CONFIG, main


def _captured(days_ago: float, name: str) -> Dataset:
    """The twin's board views, as captured ``days_ago`` days before now (the manifest's written_utc)."""
    ds, _ = board_views()
    when = datetime.now(timezone.utc) - timedelta(days=days_ago)
    manifest = {k: v for k, v in ds.manifest.items() if k not in ("format", "kind", "files")}
    files = {n: ds.image(n) for n in ds.manifest["files"]}
    return write_dataset(scratch(name) / "ds", "board_views", {**manifest, "written_utc": when.isoformat()}, files)


def _camera_part(store: Path) -> dict[str, Any]:
    doc = json.loads((store / (store / "current").read_text().strip()).read_text())
    return doc["parts"]["camera"]  # type: ignore[no-any-return]


def _calibrate(capsys: pytest.CaptureFixture[str], store: Path, ds: Dataset) -> str:
    capsys.readouterr()
    rc = main(["--config", str(DEFAULT_CONFIG), "calibrate", "camera", "--store", str(store), "--dataset", str(ds.root)])
    out = capsys.readouterr().out
    assert rc == 0, out
    return out


def test_a_recompute_of_old_views_is_dated_by_their_capture_and_expired(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old = _captured(120, "old-views")
    captured = datetime.fromisoformat(json.loads((old.root / "manifest.json").read_text())["written_utc"])
    out = _calibrate(capsys, tmp_path / "store", old)
    part = _camera_part(tmp_path / "store")
    assert abs(datetime.fromisoformat(part["calibrated_utc"]) - captured) < timedelta(seconds=1), part["calibrated_utc"]
    assert f"capture, {captured:%Y-%m-%d}" in out, out
    assert "camera: expired on" in out, out  # 120 days after the capture is past the 90 days' validity
    assert "ready for production" not in out


def test_a_recompute_of_fresh_views_is_dated_today(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    shutil.rmtree(tmp_path / "store", ignore_errors=True)
    fresh = _captured(0.01, "fresh-views")
    out = _calibrate(capsys, tmp_path / "store", fresh)
    calibrated = datetime.fromisoformat(_camera_part(tmp_path / "store")["calibrated_utc"])
    assert timedelta(0) <= datetime.now(timezone.utc) - calibrated < timedelta(hours=1)
    assert "expired" not in out and "validity runs from then" not in out, out
