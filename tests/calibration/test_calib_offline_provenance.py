"""``cellctl calibrate ... --dataset`` names who stored a version and from what: in the set file and in the cell's audit log.

The offline path needs no token and no running service, so the version it stores carries ``written_by`` (the OS account,
``cli:offline``, the host, the dataset's folder and manifest SHA-256) and the CLI appends ``calibration.store`` to the
audit log of the cell whose calibration folder it wrote (``[store] path`` under ``--workdir``). A folder that is not the
cell's (``--store`` elsewhere) is not the cell's audit log's business; an audit log that cannot be written stores nothing.
Peers: the OS (``id -un``, ``hostname``), ``json`` on the set file, ``hashlib`` on the manifest, ``sqlite3`` on audit_log.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import sqlite3
import subprocess
from pathlib import Path
from typing import Any

import pytest
from calib_test_support import board_views

from cellctl.cli import DEFAULT_CONFIG, main


def _run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = main(["--config", str(DEFAULT_CONFIG), *args])
    out = capsys.readouterr()
    return rc, out.out, out.err


def _set_file(folder: Path) -> dict[str, Any]:
    """The set in use as json reads it from the file the pointer names."""
    return json.loads((folder / (folder / "current").read_text().strip()).read_text())  # type: ignore[no-any-return]


def _audit_rows(db: Path) -> list[tuple[Any, ...]]:
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
        return conn.execute("SELECT seq, actor, source, action, params_json, prev_hash FROM audit_log ORDER BY seq").fetchall()


def test_a_version_computed_offline_names_its_writer_in_the_set_file_and_the_cells_audit_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ds, _ = board_views()
    user = subprocess.run(["id", "-un"], capture_output=True, text=True, check=True).stdout.strip()
    sha = hashlib.sha256((ds.root / "manifest.json").read_bytes()).hexdigest()
    rc, out, err = _run(capsys, "calibrate", "camera", "--workdir", str(tmp_path), "--dataset", str(ds.root))
    assert rc == 0, out + err
    assert "stored as version 1" in out and f"audit log: calibration.store by {user} (cli:offline)" in out, out
    s = _set_file(tmp_path / "var" / "calibration")
    assert s["written_by"] == {"actor": user, "source": "cli:offline", "host": socket.gethostname(),
                               "dataset": str(ds.root), "dataset_manifest_sha256": sha}  # fmt: skip
    ((seq, actor, source, action, params_json, prev),) = _audit_rows(tmp_path / "var" / "cellctl.db")
    assert (seq, actor, source, action, prev) == (1, user, "cli:offline", "calibration.store", "0" * 64)
    params = json.loads(params_json)
    assert params["version_before"] is None and params["version_after"] == 1 and params["part"] == "camera"
    assert params["part_id"] == s["parts"]["camera"]["id"] and params["dataset_manifest_sha256"] == sha
    assert params["dataset"] == str(ds.root) and params["host"] == socket.gethostname()


def test_a_folder_that_is_not_the_cells_is_not_in_its_audit_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ds, _ = board_views()
    mine = tmp_path / "mine"
    rc, out, err = _run(capsys, "calibrate", "camera", "--workdir", str(tmp_path / "cell"), "--store", str(mine),
                        "--dataset", str(ds.root))  # fmt: skip
    assert rc == 0, out + err
    assert "stored as version 1" in out and "not in an audit log" in out, out
    assert not (tmp_path / "cell").exists()  # no store file made for the cell
    assert _set_file(mine)["written_by"]["source"] == "cli:offline"


def test_an_audit_log_that_cannot_be_written_stores_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ds, _ = board_views()
    (tmp_path / "var" / "cellctl.db").mkdir(parents=True)  # [store] path is a folder: no SQLite file can be there
    rc, out, err = _run(capsys, "calibrate", "camera", "--workdir", str(tmp_path), "--dataset", str(ds.root))
    assert rc == 1, out + err
    assert "camera: not stored:" in err and "[store] path" in err and "--store DIR" in err, err
    assert "stored as version" not in out
    cal_dir = tmp_path / "var" / "calibration"
    assert not cal_dir.exists() or os.listdir(cal_dir) == []
