"""Schema 8: a store written at schema 7 whose interrupted cycles have no reason (a cellctl before the reasons) gets
recovery's reason on upgrade (as recovery words it: queued, before or after the install began), and a release that knows only schema 7 refuses the upgraded store (a rollback) instead
of failing on what it cannot read. The store is read back with sqlite3."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from cellctl.store import CellStore, SchemaTooNew, schema
from cellctl.store.records import INTERRUPTED_REASONS

V7 = schema.MIGRATIONS[:7]
ROW = ("INSERT INTO cycles (idempotency_scope, idempotency_key, recipe, part_id, source, actor, state, current_step, "
       "created_at, started_at, install_started_at, interrupted_step, interrupted_at, error) VALUES "
       "('rest', ?, 'side-window', ?, 'rest', 'op', 'interrupted', 3, '2026-01-01T00:00:00.000000+00:00', ?, ?, 3, "
       "'2026-01-01T00:01:00.000000+00:00', ?)")  # fmt: skip
BEGAN = "2026-01-01T00:00:10.000000+00:00"


def _schema_7_store(db: Path) -> None:
    conn = sqlite3.connect(db, isolation_level=None)
    assert schema.migrate(conn, V7) == (0, 7)
    conn.execute(ROW, ("q", "queued", None, None, None))
    conn.execute(ROW, ("a", "before-install", BEGAN, None, None))
    conn.execute(ROW, ("b", "after-install", BEGAN, "2026-01-01T00:00:30.000000+00:00", None))
    conn.execute(ROW, ("c", "has-a-reason", BEGAN, None, "interrupted: kept as it was"))
    conn.close()


def test_upgrade_gives_old_interrupted_cycles_their_reason_and_a_rollback_is_refused(tmp_path: Path) -> None:
    db = tmp_path / "cell.db"
    _schema_7_store(db)
    CellStore.open(db).close()
    with sqlite3.connect(db) as peer:
        assert peer.execute("PRAGMA user_version").fetchone()[0] == len(schema.MIGRATIONS) >= 8
        errors = dict(peer.execute("SELECT part_id, error FROM cycles").fetchall())
    assert errors["queued"] == INTERRUPTED_REASONS[0]  # as recovery words a cycle left queued
    assert errors["before-install"].startswith("interrupted: the service stopped before the install; nothing was "
                                               "installed, request it again with a new request id")  # fmt: skip
    assert errors["after-install"].endswith("check the glass by hand, the install is never repeated")
    assert errors["has-a-reason"] == "interrupted: kept as it was"
    # What a schema-7 release does on opening it: refuse, leaving it untouched.
    conn = sqlite3.connect(db, isolation_level=None)
    with pytest.raises(SchemaTooNew, match="newer than this cellctl knows"):
        schema.migrate(conn, V7)
    conn.close()
