"""`cellctl serve` while another process holds the store's write lock (a backup, an engineer's sqlite3 shell): one
line naming ``[store] path`` and that another process holds its lock, exit 1 (systemd's restart may find it free), no
Python traceback. The lock is held by an independent SQLite connection; the service runs as a subprocess."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from service_test_support import free_port, sim_toml

from cellctl.store import CellStore

pytestmark = pytest.mark.timeout(120)


def test_serve_with_the_store_locked_says_so_in_one_line_and_exits_1(tmp_path: Path) -> None:
    db_path = tmp_path / "var" / "cellctl.db"
    db_path.parent.mkdir()
    CellStore.open(db_path).close()  # the store of an earlier run
    config = tmp_path / "cell.toml"
    config.write_text(sim_toml(free_port()) + "\n[store]\nbusy_timeout_s = 0.3\n")
    holder = sqlite3.connect(db_path, isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")
    try:
        run = subprocess.run([sys.executable, "-m", "cellctl.cli", "--config", str(config), "serve", "--workdir", str(tmp_path)],
                             capture_output=True, text=True, timeout=90)  # fmt: skip
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    out = run.stdout + run.stderr
    assert run.returncode == 1, out
    assert "Traceback" not in out, out
    said = [line for line in out.splitlines() if "[store] path" in line]
    assert len(said) == 1 and str(db_path) in said[0] and "another process holds" in said[0], out
