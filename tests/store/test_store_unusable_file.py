"""A database file the store cannot use (another file, a damaged one, a newer schema) is refused when it is opened,
naming [store] path and the fix; `cellctl serve` says so in one line and exits 1 instead of a traceback, or
instead of serving on a damaged file whose writes fail later."""

from __future__ import annotations

import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from test_store_path import serve_config

from cellctl.store import CellStore, SchemaTooNew, StoreError

FIX = "restore it from a backup, or move it aside to start an empty store"


def _store_file(folder: Path, rows: int = 0) -> Path:
    """A store's database with ``rows`` rows of padding in a table of its own, checkpointed into the main file."""
    db = folder / "cellctl.db"
    CellStore.open(db).close()
    conn = sqlite3.connect(db, isolation_level=None)
    conn.execute("CREATE TABLE pad (a INTEGER PRIMARY KEY, b TEXT)")
    conn.execute("CREATE INDEX pad_b ON pad (b)")
    conn.executemany("INSERT INTO pad (b) VALUES (?)", [(f"row {i} " * 5,) for i in range(rows)])
    conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    conn.close()
    return db


def _overwrite(db: Path, offset: int, data: bytes) -> None:
    raw = bytearray(db.read_bytes())
    raw[offset : offset + len(data)] = data
    db.write_bytes(bytes(raw))


def _sqlite_says_damaged(db: Path) -> bool:
    """SQLite's own full check (the independent judge) finds the file damaged."""
    conn = sqlite3.connect(db)
    try:
        return conn.execute("PRAGMA integrity_check").fetchall() != [("ok",)]
    except sqlite3.DatabaseError:
        return True
    finally:
        conn.close()


def _damaged_page(folder: Path) -> Path:
    db = _store_file(folder)
    _overwrite(db, 4096 * 2, b"\xff" * 200)  # one page's header overwritten, as a disk fault does
    return db


def _damaged_cells(folder: Path) -> Path:
    """A file whose header pages are intact but one b-tree page's free-space bookkeeping is wrong."""
    db = _store_file(folder, rows=3000)
    for page in range(3, db.stat().st_size // 4096):
        trial = folder / "trial.db"
        shutil.copy(db, trial)
        _overwrite(trial, page * 4096 + 2000, b"\x07" * 50)
        if _sqlite_says_damaged(trial):
            trial.replace(db)
            return db
    raise AssertionError("no page whose damage SQLite notices")


def _newer_schema(folder: Path) -> Path:
    db = folder / "cellctl.db"
    conn = sqlite3.connect(db)
    conn.execute("PRAGMA user_version = 99")
    conn.commit()
    conn.close()
    return db


def _not_sqlite(folder: Path) -> Path:
    db = folder / "cellctl.db"
    db.write_bytes(b"this is not sqlite\n" * 500)
    return db


@pytest.mark.parametrize("make", [_damaged_page, _damaged_cells, _not_sqlite])
def test_a_file_that_is_not_intact_sqlite_is_refused_naming_it_and_the_fix(tmp_path: Path, make: object) -> None:
    db = make(tmp_path)  # type: ignore[operator]
    assert _sqlite_says_damaged(db)
    with pytest.raises(StoreError) as err:  # StoreDamaged
        CellStore.open(db)
    text = str(err.value)
    assert text.startswith(f"[store] path {db} ") and FIX in text and "\n" not in text, text
    assert isinstance(err.value, OSError)  # the CLI prints an OSError in one line


def test_an_intact_file_still_opens(tmp_path: Path) -> None:
    db = _store_file(tmp_path, rows=3000)
    CellStore.open(db).close()
    assert not _sqlite_says_damaged(db)


def test_a_newer_schema_names_the_file(tmp_path: Path) -> None:
    db = _newer_schema(tmp_path)
    with pytest.raises(SchemaTooNew, match=rf"^\[store\] path {db}: the database is at schema version 99, newer"):
        CellStore.open(db)


@pytest.mark.parametrize("make", [_damaged_page, _newer_schema, _not_sqlite])
def test_serve_refuses_in_one_line_naming_the_file(tmp_path: Path, make: object) -> None:
    (tmp_path / "var").mkdir()
    db = make(tmp_path / "var")  # type: ignore[operator]
    cfg = serve_config(tmp_path, db)
    try:
        run = subprocess.run([sys.executable, "-m", "cellctl", "--config", str(cfg), "serve", "--workdir", str(tmp_path / "wd")],
                             capture_output=True, text=True, timeout=60)  # fmt: skip
    except subprocess.TimeoutExpired:
        raise AssertionError(f"serve started on {db} and kept running") from None
    # A store of a later release: exit 2 (README, Exit status), so the systemd unit does not restart what cannot start
    assert run.returncode == (2 if make is _newer_schema else 1), run.stderr[-2000:]
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: [store] path {db}"), run.stderr[-2000:]
