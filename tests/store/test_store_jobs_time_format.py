"""Commissioning job times are stored as every other time of the store (``connection.ts``: ISO 8601 in
UTC with microseconds), so they compare and sort as text like the cycles' times, whatever the clock's
zone and however many microseconds."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone
from pathlib import Path

from cellctl.store import CellStore


def test_job_times_are_stored_in_the_stores_format(tmp_path: Path) -> None:
    t = [datetime(2026, 3, 1, 9, 0, tzinfo=timezone(timedelta(hours=1)))]  # a clock in CET, zero microseconds
    with CellStore.open(tmp_path / "c.db", clock=lambda: t[0]) as store:
        done = store.create_job("verify", actor="op", source="cli", options={}, version_before=None).id
        store.update_job(done, state="done")
        store.create_job("hand_eye", actor="op", source="cli", options={}, version_before=None)
        store.recover_jobs()
        rows = store._conn.execute("SELECT created_at, finished_at FROM jobs ORDER BY id").fetchall()
    assert [v for row in rows for v in row] == ["2026-03-01T08:00:00.000000+00:00"] * 4  # as connection.ts writes
