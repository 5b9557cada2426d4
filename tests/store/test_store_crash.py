"""Store: kill -9 for real, recovery, the never-repeated install, and schema migrations."""

from __future__ import annotations

import os
import selectors
import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cellctl.cell.tags import CycleStep
from cellctl.store import (
    CellStore,
    CycleRequest,
    CycleState,
    CycleStateError,
    InstallAlreadyStarted,
    SchemaTooNew,
    StoreError,
)
from cellctl.store import schema

# The child does what the orchestrator does, then waits to be killed mid-step.
CHILD = textwrap.dedent(
    """
    import sys, time
    from cellctl.cell.tags import CycleStep
    from cellctl.store import CellStore, CycleRequest

    db, last_step = sys.argv[1], CycleStep[sys.argv[2]]
    store = CellStore.open(db)
    done = store.submit_cycle(CycleRequest("side-window-A", "P-0", "CAR-1"), scope="plc", key="41", actor="plc")
    store.start_cycle(done.cycle.id)
    store.complete_cycle(done.cycle.id, result={"ok": True})
    cid = store.submit_cycle(CycleRequest("side-window-A", "P-1", "CAR-1"), scope="plc", key="42", actor="plc").cycle.id
    store.submit_cycle(CycleRequest("side-window-A", "P-2", "CAR-2"), scope="plc", key="43", actor="plc")
    store.claim_key("rest-cmd", "c-open", {"command": "stop"})
    store.start_cycle(cid)
    for step in CycleStep:
        if step == CycleStep.NONE:
            continue
        store.begin_step(cid, step)  # for INSTALL: the marker, committed before the robot moves
        if step == last_step:
            break
        store.finish_step(cid, step, ok=True, figures={"step": step.name})
    print("READY", cid, flush=True)
    time.sleep(60)
    """
)


def run_and_kill(db: Path, last_step: CycleStep) -> int:
    """Start the child, wait until it is inside ``last_step``, SIGKILL it; returns the cycle id."""
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(db), last_step.name],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        sel = selectors.DefaultSelector()
        sel.register(proc.stdout, selectors.EVENT_READ)  # type: ignore[arg-type]
        if not sel.select(timeout=20.0):
            raise AssertionError(f"child never got ready: {proc.stderr.read() if proc.poll() is not None else ''}")
        line = proc.stdout.readline()  # type: ignore[union-attr]
        assert line.startswith("READY"), f"child said {line!r}; stderr: {proc.stderr.read()}"  # type: ignore[union-attr]
        os.kill(proc.pid, signal.SIGKILL)
        assert proc.wait(timeout=10.0) == -signal.SIGKILL
        return int(line.split()[1])
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10.0)
        proc.stdout.close()  # type: ignore[union-attr]
        proc.stderr.close()  # type: ignore[union-attr]


def test_kill_9_during_install_is_recorded_and_the_install_never_repeats(tmp_path: Path) -> None:
    db = tmp_path / "cell.db"
    cid = run_and_kill(db, CycleStep.INSTALL)
    with CellStore.open(db) as store:
        report = store.recover()
        interrupted = {i.cycle_id: i for i in report.interrupted}
        assert interrupted[cid].step == CycleStep.INSTALL and interrupted[cid].install_started
        assert not interrupted[cid].resumable and interrupted[cid].was == CycleState.RUNNING
        queued = [i for i in report.interrupted if i.cycle_id != cid]
        assert [(i.was, i.step, i.install_started) for i in queued] == [(CycleState.QUEUED, CycleStep.NONE, False)]
        assert report.keys_released == 1  # the open command claim

        rec = store.cycle(cid)
        assert rec.state == CycleState.INTERRUPTED and rec.interrupted_step == CycleStep.INSTALL
        assert rec.install_started and rec.interrupted_at is not None
        assert rec.error is not None and "after the install began" in rec.error and "never repeated" in rec.error
        assert "before the cycle began" in (store.cycle(queued[0].cycle_id).error or "")
        assert [(s.step, s.ok) for s in rec.steps] == [
            (CycleStep.CALIBRATE, True), (CycleStep.ALIGN, True), (CycleStep.SHOOT, True),
            (CycleStep.COMPENSATE, True), (CycleStep.INSTALL, None)]  # fmt: skip
        assert rec.steps[-1].error is not None and "interrupted" in rec.steps[-1].error
        assert store.cycles(state=CycleState.DONE)[0].result == {"ok": True}  # finished work untouched

        with pytest.raises(InstallAlreadyStarted, match="never repeated"):
            store.resume_cycle(cid)
        with pytest.raises(CycleStateError):
            store.begin_step(cid, CycleStep.INSTALL)
        # The PLC repeating its request id gets the interrupted cycle back, not a new install.
        again = store.submit_cycle(CycleRequest("side-window-A", "P-1", "CAR-1"), scope="plc", key="42", actor="plc")
        assert not again.created and again.cycle.id == cid and again.cycle.state == CycleState.INTERRUPTED
        assert store.recover().interrupted == ()  # a second recovery finds nothing


def test_kill_9_before_install_can_resume(tmp_path: Path) -> None:
    db = tmp_path / "cell.db"
    cid = run_and_kill(db, CycleStep.ALIGN)
    with CellStore.open(db) as store:
        report = store.recover()
        mine = next(i for i in report.interrupted if i.cycle_id == cid)
        assert (mine.step, mine.install_started, mine.resumable) == (CycleStep.ALIGN, False, True)
        assert "before the install; nothing was installed" in (store.cycle(cid).error or "")
        resumed = store.resume_cycle(cid)
        assert resumed.state == CycleState.RUNNING and resumed.interrupted_step == CycleStep.ALIGN
        assert resumed.error is None  # running again: its reason is gone with the interruption
        assert store.begin_step(cid, CycleStep.ALIGN).attempt == 2
        store.finish_step(cid, CycleStep.ALIGN, ok=True, figures={})
        store.begin_step(cid, CycleStep.INSTALL)
        assert store.complete_cycle(cid, result={"ok": True}).state == CycleState.DONE
        with pytest.raises(CycleStateError, match="only an interrupted cycle"):
            store.resume_cycle(cid)


# --- migrations ----------------------------------------------------------------------------------


def test_migrations_run_once_and_track_user_version(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    db = tmp_path / "cell.db"
    CellStore.open(db).close()
    raw = sqlite3.connect(db)
    n = len(schema.MIGRATIONS)
    assert raw.execute("PRAGMA user_version").fetchone()[0] == n >= 2
    raw.close()
    extra = "ALTER TABLE cycles ADD COLUMN operator_note TEXT;"
    monkeypatch.setattr(schema, "MIGRATIONS", (*schema.MIGRATIONS, extra))
    conn = sqlite3.connect(db, isolation_level=None)
    assert schema.migrate(conn, schema.MIGRATIONS) == (n, n + 1)
    assert schema.migrate(conn, schema.MIGRATIONS) == (n + 1, n + 1)  # nothing left to do
    cols = [r[1] for r in conn.execute("PRAGMA table_info(cycles)")]
    assert cols.count("operator_note") == 1
    conn.close()


def test_a_failing_migration_leaves_the_previous_version(tmp_path: Path) -> None:
    db = tmp_path / "cell.db"
    CellStore.open(db).close()
    conn = sqlite3.connect(db, isolation_level=None)
    bad = "CREATE TABLE extra (x INTEGER); INSERT INTO no_such_table VALUES (1);"
    n = len(schema.MIGRATIONS)
    with pytest.raises(StoreError, match=f"migration to schema version {n + 1} failed"):
        schema.migrate(conn, (*schema.MIGRATIONS, bad))
    assert schema.schema_version(conn) == n
    assert conn.execute("SELECT name FROM sqlite_master WHERE name = 'extra'").fetchone() is None
    conn.close()


def test_a_newer_database_is_refused(tmp_path: Path) -> None:
    db = tmp_path / "cell.db"
    raw = sqlite3.connect(db)
    raw.execute("PRAGMA user_version = 99")
    raw.close()
    with pytest.raises(SchemaTooNew, match="schema version 99, newer than this cellctl knows"):
        CellStore.open(db)
