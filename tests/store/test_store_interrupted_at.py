"""A cycle the service died in is dated when it was cut off, not when the next start found it: ``interrupted_at`` is
the newest of its steps' starts and ends and its images (else its start, else its submission), and the time recovery
found it is kept on its own (``interrupted_found_at``). The shift counts take the cut-off; a ``GET /parts`` window
takes the found time, so an MES that polled a window while the cycle still ran still gets it once. Stores written
before (schema 8) get both times from what they recorded. Peer: sqlite3 reads the file; the times are the test's."""

from __future__ import annotations

import sqlite3
from collections.abc import Callable
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import pytest

from cellctl.api.dashboard import count_shift
from cellctl.domain import CycleStep
from cellctl.store import CellStore, CycleRequest, CycleState, schema

T0 = datetime(2026, 3, 1, 21, 50, tzinfo=timezone.utc)
FOUND = datetime(2026, 3, 2, 6, 10, tzinfo=timezone.utc)  # the power came back the next morning


class Clock:
    """A clock the test sets (each store call stamps rows with ``now``)."""

    def __init__(self, now: datetime) -> None:
        self.now = now

    def __call__(self) -> datetime:
        return self.now

    def at(self, seconds: float) -> Clock:
        self.now = T0 + timedelta(seconds=seconds)
        return self


def _submit(store: CellStore, clock: Clock, part: str) -> int:
    clock.at(0)
    return store.submit_cycle(CycleRequest("side-window", part, "CAR-1"), scope="t", key=part, actor="t").cycle.id


def _queued(store: CellStore, clock: Clock) -> int:
    return _submit(store, clock, "queued")


def _started(store: CellStore, clock: Clock) -> int:
    cid = _submit(store, clock, "started")
    clock.at(1)
    store.start_cycle(cid)
    return cid


def _in_install(store: CellStore, clock: Clock) -> int:
    cid = _submit(store, clock, "in-install")
    clock.at(1), store.start_cycle(cid)
    clock.at(2), store.begin_step(cid, CycleStep.ALIGN)
    clock.at(5), store.finish_step(cid, CycleStep.ALIGN, ok=True, figures={})
    clock.at(7), store.begin_step(cid, CycleStep.INSTALL)
    return cid


def _step_ended(store: CellStore, clock: Clock) -> int:
    cid = _submit(store, clock, "step-ended")
    clock.at(1), store.start_cycle(cid)
    clock.at(2), store.begin_step(cid, CycleStep.ALIGN)
    clock.at(6), store.finish_step(cid, CycleStep.ALIGN, ok=True, figures={})
    return cid


def _image_last(store: CellStore, clock: Clock) -> int:
    cid = _submit(store, clock, "image-last")
    clock.at(1), store.start_cycle(cid)
    clock.at(7), store.begin_step(cid, CycleStep.SHOOT)
    clock.at(9), store.add_image(cid, CycleStep.SHOOT, name="shot1", uri="cycle-1-shot1.png")
    return cid


CASES: dict[str, tuple[Callable[[CellStore, Clock], int], float]] = {
    "queued": (_queued, 0),  # never started: its submission
    "started": (_started, 1),  # started, no step yet: its start
    "in-install": (_in_install, 7),  # the open install step's start
    "step-ended": (_step_ended, 6),  # the last step's end
    "image-last": (_image_last, 9),  # an image after the last step began
}


def _read(db: Path, cid: int, *columns: str) -> tuple[Any, ...]:
    """The cycle's ``columns`` as sqlite3 reads the file, times as datetimes."""
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as peer:
        row = peer.execute(f"SELECT {', '.join(columns)} FROM cycles WHERE id = ?", (cid,)).fetchone()
    return tuple(datetime.fromisoformat(v) if c.endswith("_at") and v is not None else v for c, v in zip(columns, row, strict=True))


@pytest.mark.parametrize("case", list(CASES))
def test_recovery_dates_the_cycle_at_its_last_trace_and_keeps_when_it_found_it(tmp_path: Path, case: str) -> None:
    db, clock = tmp_path / "cell.db", Clock(T0)
    left_behind, last_trace_s = CASES[case]
    with CellStore.open(db, clock=clock) as store:
        cid = left_behind(store, clock)
    clock.now = FOUND
    with CellStore.open(db, clock=clock) as store:
        assert [c.cycle_id for c in store.recover().interrupted] == [cid]
        record = store.cycle(cid)
    assert _read(db, cid, "state", "interrupted_at") == ("interrupted", T0 + timedelta(seconds=last_trace_s))
    assert record.state is CycleState.INTERRUPTED and record.interrupted_at == T0 + timedelta(seconds=last_trace_s)
    assert _read(db, cid, "interrupted_found_at") == (FOUND,)


def test_a_clock_stepped_back_before_the_restart_never_dates_it_after_it_was_found(tmp_path: Path) -> None:
    db, clock = tmp_path / "cell.db", Clock(T0)
    with CellStore.open(db, clock=clock) as store:
        cid = _in_install(store, clock)  # steps at T0 + 2 s, 5 s, 7 s
    clock.now = T0 + timedelta(seconds=3)  # the wall clock was set back 4 s while the service was down
    with CellStore.open(db, clock=clock) as store:
        store.recover()
    assert _read(db, cid, "interrupted_at") == (T0 + timedelta(seconds=2),)  # the last trace not after it was found
    assert _read(db, cid, "interrupted_found_at") == (T0 + timedelta(seconds=3),)


def test_the_shift_counts_take_the_cut_off_and_an_export_window_the_found_time_once(tmp_path: Path) -> None:
    db, clock = tmp_path / "cell.db", Clock(T0)
    with CellStore.open(db, clock=clock) as store:
        cid = _in_install(store, clock)  # cut off during the install, at T0 + 7 s (21:50:07)
        clock.now = datetime(2026, 3, 1, 22, 0, 1, tzinfo=timezone.utc)
        # The MES exports the late shift while the cycle still runs (held, say): it is not ended, so not listed.
        late = (datetime(2026, 3, 1, 14, 0, tzinfo=timezone.utc), datetime(2026, 3, 1, 22, 0, tzinfo=timezone.utc))
        assert store.part_installs(since=late[0], until=late[1]).installs == ()
    clock.now = FOUND
    with CellStore.open(db, clock=clock) as store:
        store.recover()
        clock.now = datetime(2026, 3, 2, 14, 0, 1, tzinfo=timezone.utc)  # the morning shift is over: its window is whole
        night = (late[1], datetime(2026, 3, 2, 6, 0, tzinfo=timezone.utc))
        morning = (night[1], datetime(2026, 3, 2, 14, 0, tzinfo=timezone.utc))
        listed = {w: [i.record.id for i in store.part_installs(since=w[0], until=w[1]).installs] for w in (late, night, morning)}
        record = store.cycle(cid)
    # Back-to-back windows list it exactly once: in the one after the restart (the late one was exported already).
    assert listed == {late: [], night: [], morning: [cid]}, listed
    # Its record says when it was cut off: the late shift counts it as a not OK part, the morning shift does not.
    assert record.interrupted_at == T0 + timedelta(seconds=7)
    assert count_shift([record], *late) == (0, 1, None)
    assert count_shift([record], *morning) == (0, 0, None)


ROW = ("INSERT INTO cycles (id, idempotency_scope, idempotency_key, recipe, part_id, source, actor, state, current_step, "
       "created_at, started_at, finished_at, install_started_at, interrupted_step, interrupted_at, error) VALUES "
       "(?, 't', ?, 'side-window', ?, 't', 't', ?, 0, ?, ?, ?, NULL, NULL, ?, NULL)")  # fmt: skip
STEP = "INSERT INTO cycle_steps (cycle_id, step, attempt, started_at, finished_at) VALUES (?, ?, 1, ?, ?)"
IMAGE = "INSERT INTO cycle_images (cycle_id, step, name, uri, created_at) VALUES (?, 3, ?, ?, ?)"


def _t(seconds: float) -> str:
    return (T0 + timedelta(seconds=seconds)).strftime("%Y-%m-%dT%H:%M:%S.%f+00:00")


def test_upgrade_gives_cycles_interrupted_before_their_cut_off_and_keeps_when_they_were_found(tmp_path: Path) -> None:
    db = tmp_path / "cell.db"
    found = (FOUND - T0).total_seconds()
    conn = sqlite3.connect(db, isolation_level=None)
    assert schema.migrate(conn, schema.MIGRATIONS[:8]) == (0, 8)
    conn.execute(ROW, (1, "a", "stepped", "interrupted", _t(0), _t(1), None, _t(found)))
    conn.execute(STEP, (1, 2, _t(2), _t(5)))
    conn.execute(STEP, (1, 5, _t(7), None))
    conn.execute(IMAGE, (1, "shot1", "u1", _t(6)))
    conn.execute(ROW, (2, "b", "queued", "interrupted", _t(0), None, None, _t(found)))
    # Interrupted, resumed after the restart (its install never began) and done: only what came before counts.
    conn.execute(ROW, (3, "c", "resumed", "done", _t(0), _t(1), _t(found + 60), _t(found)))
    conn.execute(STEP, (3, 2, _t(3), None))
    conn.execute(STEP, (3, 3, _t(found + 10), _t(found + 20)))
    conn.execute(ROW, (4, "d", "finished", "done", _t(0), _t(1), _t(30), None))
    conn.close()
    with CellStore.open(db) as store:
        windows = [i.record.id for i in store.part_installs(since=FOUND, until=FOUND + timedelta(hours=1)).installs]
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as peer:
        assert peer.execute("PRAGMA user_version").fetchone()[0] == len(schema.MIGRATIONS) >= 9
        rows = {r[0]: r[1:] for r in peer.execute("SELECT id, interrupted_at, interrupted_found_at FROM cycles")}
    assert rows == {1: (_t(7), _t(found)), 2: (_t(0), _t(found)), 3: (_t(3), _t(found)), 4: (None, None)}, rows
    assert windows == [1, 2, 3]  # a window lists them where it did before the upgrade: found, or resumed and done
