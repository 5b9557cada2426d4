"""A store of an earlier release is copied, whole, before its migration: the copy (read with sqlite3) is the store as
it was, at its schema, with the commits still in the WAL; the served cell logs and audits the migration; a store of a
later release (a rollback) is refused naming the copy to put back (`serve` then exits 2: test_store_unusable_file)."""

from __future__ import annotations

import logging
import sqlite3
from pathlib import Path

import pytest
from service_test_support import api_client, running_service

from cellctl.store import CellStore, SchemaTooNew, schema

V7 = schema.MIGRATIONS[:7]
ROW = ("INSERT INTO cycles (idempotency_scope, idempotency_key, recipe, part_id, source, actor, state, current_step, "
       "created_at) VALUES ('rest', ?, 'side-window', ?, 'rest', 'op', 'queued', 0, '2026-01-01T00:00:00.000000+00:00')")


def _schema_7_store(db: Path, rows: int) -> sqlite3.Connection:
    """A store as release schema 7 left it, its last commits still in the WAL (the connection stays open)."""
    db.parent.mkdir(parents=True, exist_ok=True)
    conn = sqlite3.connect(db, isolation_level=None)
    conn.execute("PRAGMA journal_mode = WAL")
    conn.execute("PRAGMA wal_autocheckpoint = 0")
    assert schema.migrate(conn, V7) == (0, 7)
    for k in range(rows):
        conn.execute(ROW, (f"k{k}", f"G/{k}"))
    return conn


def _peer(db: Path) -> tuple[int, int]:
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as c:
        return c.execute("PRAGMA user_version").fetchone()[0], c.execute("SELECT count(*) FROM cycles").fetchone()[0]


def test_a_store_of_an_earlier_schema_is_copied_whole_before_it_is_migrated(tmp_path: Path) -> None:
    db = tmp_path / "cellctl.db"
    old = _schema_7_store(db, rows=40)
    try:
        assert (tmp_path / "cellctl.db-wal").stat().st_size > 0  # the rows are in the WAL, not yet in the file
        store = CellStore.open(db)
        try:
            up = store.upgrade
            assert up is not None and (up.from_version, up.to_version) == (7, len(schema.MIGRATIONS))
        finally:
            store.close()
    finally:
        old.close()
    copies = sorted(tmp_path.glob("cellctl.db.schema7-*.bak"))
    assert copies == [up.kept_copy], copies
    assert _peer(copies[0]) == (7, 40)  # the store as release 7 left it, every row
    assert _peer(db) == (len(schema.MIGRATIONS), 40)
    CellStore.open(db).close()  # already current: no second copy
    assert sorted(tmp_path.glob("cellctl.db.schema*.bak")) == copies
    new = CellStore.open(tmp_path / "new.db")  # a new store: nothing to keep
    assert new.upgrade is None
    new.close()
    assert not list(tmp_path.glob("new.db.schema*"))


def test_a_rollback_is_refused_naming_the_copy_to_put_back(tmp_path: Path) -> None:
    db = tmp_path / "cellctl.db"
    latest = len(schema.MIGRATIONS)
    kept = tmp_path / f"cellctl.db.schema{latest}-20261201T080000Z.bak"  # as the upgrade from this release kept it
    with sqlite3.connect(db) as c:
        c.execute(f"PRAGMA user_version = {latest + 1}")
    kept.write_bytes(db.read_bytes())
    with pytest.raises(SchemaTooNew) as err:
        CellStore.open(db)
    assert str(kept) in str(err.value) and "later release" in str(err.value), err.value


async def test_the_served_cell_logs_and_audits_the_migration(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    _schema_7_store(tmp_path / "var" / "cellctl.db", rows=3).close()
    caplog.set_level(logging.WARNING, logger="cellctl")
    async with running_service(tmp_path) as service, api_client(service) as client:
        cycles = (await client.get("/cycles")).json()
        assert len(cycles["cycles"] if isinstance(cycles, dict) else cycles) >= 3
    copy, = (tmp_path / "var").glob("cellctl.db.schema7-*.bak")
    said = [r.getMessage() for r in caplog.records if "migrated from schema 7" in r.getMessage()]
    assert len(said) == 1 and str(copy) in said[0], said
    with sqlite3.connect(tmp_path / "var" / "cellctl.db") as c:
        entries = c.execute("SELECT actor, action, params_json FROM audit_log WHERE action = 'store.migrated'").fetchall()
    assert len(entries) == 1 and entries[0][0] == "system" and str(copy) in entries[0][2], entries

