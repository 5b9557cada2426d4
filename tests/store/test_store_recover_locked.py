"""Startup's recovery while another process (a backup, an sqlite3 shell) holds the database's write lock: asked again a
bounded number of times, then StoreLocked naming ``[store] path`` and the way out; once the lock is gone it runs."""

from __future__ import annotations

import sqlite3
import time
from pathlib import Path

import pytest

from cellctl.store import CellStore, CycleRequest, StoreError

BUSY_S = 0.2


def test_recovery_under_another_process_s_lock_names_the_store_then_runs_once_it_is_free(tmp_path: Path) -> None:
    path = tmp_path / "cellctl.db"
    with CellStore.open(path, busy_timeout_s=BUSY_S) as store:
        cid = store.submit_cycle(CycleRequest("side-window", "P-1"), scope="t", key="k", actor="t").cycle.id
        store.start_cycle(cid)  # left running by a process that died
        holder = sqlite3.connect(path, isolation_level=None)  # an independent connection
        holder.execute("BEGIN EXCLUSIVE")
        try:
            t0 = time.monotonic()
            with pytest.raises(StoreError) as caught:
                store.recover()
            took = time.monotonic() - t0
        finally:
            holder.execute("ROLLBACK")
            holder.close()
        said = str(caught.value)
        assert said.startswith(f"[store] path {path}: another process holds the database's lock"), said
        assert "\n" not in said and "fuser" in said, said
        assert 2 * BUSY_S <= took < 10 * BUSY_S + 2.0, took  # bounded: asked again, then said
        assert [i.cycle_id for i in store.recover().interrupted] == [cid]  # free again: the recovery runs
    db = sqlite3.connect(path)
    try:
        assert db.execute("SELECT state FROM cycles WHERE id = ?", (cid,)).fetchone() == ("interrupted",)
    finally:
        db.close()
