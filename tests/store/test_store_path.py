"""A [store] path that cannot be the database file is refused naming the setting and the fix (no traceback)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from cellctl.store import CellStore, StoreError
from cellctl.store.connection import StorePathError, make_store_folder

ROOT = Path(__file__).resolve().parents[2]


def test_a_folder_is_refused_naming_the_setting(tmp_path: Path) -> None:
    with pytest.raises(StorePathError, match=r"\[store\] path .* is a folder; the store is one SQLite file") as err:
        CellStore.open(tmp_path)
    assert f'path = "{tmp_path / "cellctl.db"}"' in str(err.value)
    assert isinstance(err.value, StoreError) and isinstance(err.value, OSError)  # the CLI prints an OSError in one line


@pytest.mark.parametrize("under", ["cell.db", "sub/cell.db"])
def test_a_path_under_a_regular_file_is_refused_naming_the_file(tmp_path: Path, under: str) -> None:
    (tmp_path / "afile").write_text("x")
    db = tmp_path / "afile" / under
    expected = rf"\[store\] path {db} lies under {tmp_path / 'afile'}, which is a file, not a folder; change \[store\] path"
    with pytest.raises(StorePathError, match=expected):
        make_store_folder(db)  # the service makes the folder first
    with pytest.raises(StorePathError, match=expected):
        CellStore.open(db)


def test_a_missing_folder_is_still_named(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match=r"its folder .*missing does not exist: create it or change \[store\] path"):
        CellStore.open(tmp_path / "missing" / "cell.db")
    make_store_folder(tmp_path / "missing" / "cell.db")
    CellStore.open(tmp_path / "missing" / "cell.db").close()


def serve_config(tmp_path: Path, store: Path) -> Path:
    """config/sim.toml with every port 0, no self-commissioning and ``[store] path = store``, as tmp_path/cell.toml."""
    text = (ROOT / "config" / "sim.toml").read_text()
    for old, new in [("port = 5020", "port = 0"), ("port = 4840 ", "port = 0 "), ("port = 8080", "port = 0"),
                     ("auto_calibrate_in_sim = true", "auto_calibrate_in_sim = false"),
                     ("[store.retention]", f'[store]\npath = "{store}"\n\n[store.retention]')]:  # fmt: skip
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text)
    return cfg


@pytest.mark.parametrize("case", ["folder", "under_a_file"])
def test_serve_says_which_setting_to_change(tmp_path: Path, case: str) -> None:
    (tmp_path / "afolder").mkdir()
    (tmp_path / "afile").write_text("x")
    store = tmp_path / "afolder" if case == "folder" else tmp_path / "afile" / "cellctl.db"
    cfg = serve_config(tmp_path, store)
    run = subprocess.run([sys.executable, "-m", "cellctl", "--config", str(cfg), "serve", "--workdir", str(tmp_path / "wd")],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert run.returncode == 2, run.stderr[-2000:]  # a configuration problem: systemd does not restart on 2
    assert "Traceback" not in run.stderr and f"error: [store] path {store}" in run.stderr, run.stderr[-2000:]
