"""The export window's end stamp: it never goes back when the wall clock steps back, so back-to-back windows list
every ended cycle exactly once across clock steps, restarts (recovery's interrupted cycles) and retention.

A cycle's ``ended_at`` is the store's clock, but never before the latest end stamp + 1 us (kept in one row, not
found by a scan); the bound a window applies is never later than that latest + 1 us (nor the ``until`` asked) and
never earlier than ``since``. ``finished_at`` keeps the wall clock's time. Peer: sqlite3 reads the store file; the
clock is the test's, stepped as NTP steps a PC's.
"""

from __future__ import annotations

import logging
import sqlite3
from collections.abc import Callable
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from cellctl.domain import CycleStep
from cellctl.store import CellStore, CycleRequest, schema

T0 = datetime(2026, 12, 6, 6, 0, tzinfo=timezone.utc)
US = timedelta(microseconds=1)
FAR = datetime(2999, 1, 1, tzinfo=timezone.utc)


class Clock:
    """The store's wall clock, set and stepped by the test."""

    def __init__(self) -> None:
        self.now = T0

    def __call__(self) -> datetime:
        return self.now

    def step(self, seconds: float) -> None:
        self.now += timedelta(seconds=seconds)


def run(store: CellStore, clock: Clock, key: str, *, ok: bool = True) -> int:
    """One cycle, submitted and ended within a second of the clock."""
    cid = store.submit_cycle(CycleRequest("side-window", key, "CAR-1", "plc"), scope="t", key=key, actor="t").cycle.id
    store.start_cycle(cid)
    clock.step(0.5)
    if ok:
        store.complete_cycle(cid, result={"ok": True})
    else:
        store.fail_cycle(cid, error="corner not found")
    clock.step(0.5)
    return cid


class Mes:
    """An MES exporting periodically: each window's ``since`` is the bound the previous one applied.

    ``until``: what it asks (a fixed time far ahead, or its own clock, the host's); a run whose ``until`` is not
    later than ``since`` is refused (ValueError) and tried again at the next period."""

    def __init__(self, store: CellStore, until: Callable[[], datetime], since: datetime) -> None:
        self.store, self.until, self.since = store, until, since
        self.got: list[int] = []
        self.outside: list[tuple[int, datetime | None]] = []  # listed, but its end stamp is not in the window

    def export(self) -> None:
        until = self.until()
        if until <= self.since:
            with pytest.raises(ValueError, match="must be later than since"):
                self.store.part_installs(since=self.since, until=until)
            return
        after, bound = None, until
        while True:
            page = self.store.part_installs(since=self.since, until=bound, after_id=after, limit=2)
            assert page.until is not None and page.until <= bound
            bound = max(page.until, self.since)  # (never answered earlier than since: checked in test_the_bound_applied)
            self.got += [i.record.id for i in page.installs]
            for i in page.installs:
                if not ((at := getattr(i, "ended_at", None)) is not None and self.since <= at < bound):
                    self.outside.append((i.record.id, at))
            if (after := page.next_after) is None:
                break
        self.since = bound


def ended(path: Path, column: str = "finished_at") -> list[tuple[int, str, str | None]]:
    """(id, state, ``column``) of every ended cycle, by id, read by sqlite3."""
    with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as peer:
        return [
            (int(r[0]), r[1], r[2])
            for r in peer.execute(
                f"SELECT id, state, {column} FROM cycles WHERE state IN ('done', 'failed', 'interrupted') ORDER BY id"
            )
        ]


def test_back_to_back_windows_list_every_end_once_across_clock_steps_and_a_restart(tmp_path: Path) -> None:
    path, clock = tmp_path / "cell.db", Clock()
    store = CellStore.open(path, clock=clock)
    mes = [Mes(store, lambda: FAR, T0 - timedelta(days=1)), Mes(store, clock, T0 - timedelta(days=1))]

    def export() -> None:
        for m in mes:
            m.export()

    run(store, clock, "G-1")
    export()
    clock.step(-30)  # NTP steps the clock back 30 s
    run(store, clock, "G-2")
    export()
    run(store, clock, "G-3", ok=False)
    clock.step(-3600)  # and again, 1 h
    run(store, clock, "G-4")
    export()
    clock.step(3630 + 7200)  # ahead 2 h (a clock set wrong) ...
    run(store, clock, "G-5")
    export()
    clock.step(-7200)  # ... which NTP corrects
    run(store, clock, "G-6")
    export()
    cid = store.submit_cycle(CycleRequest("side-window", "G-7", "CAR-1", "plc"), scope="t", key="G-7", actor="t").cycle.id
    store.start_cycle(cid)
    store.begin_step(cid, CycleStep.ALIGN)
    export()
    store.close()  # the service dies in G-7's cycle; the PC restarts on a clock 10 min behind
    clock.step(-600)
    store = CellStore.open(path, clock=clock)
    for m in mes:
        m.store = store
    assert [c.cycle_id for c in store.recover().interrupted] == [cid]
    export()
    run(store, clock, "G-8")
    export()
    clock.step(3 * 3600)  # much later: the MES on its own clock has caught up with every end stamp
    export()
    store.close()

    truth = ended(path)
    assert [r[0] for r in truth] == list(range(1, 9)) and truth[6][1] == "interrupted"
    for m in mes:
        assert sorted(m.got) == [r[0] for r in truth], f"exported {m.got}, ended {[r[0] for r in truth]}"
        assert m.outside == []
    stamps = [datetime.fromisoformat(str(r[2])) for r in ended(path, "ended_at")]
    assert all(a < b for a, b in zip(stamps, stamps[1:], strict=False)), stamps  # never back
    # The wall clock's time is kept as it was read: G-2 finished 30 s before G-1, by the stepped clock.
    finished = {r[0]: datetime.fromisoformat(r[2]) for r in truth if r[2] is not None}
    assert finished[2] < finished[1] and stamps[1] == stamps[0] + US


def test_the_bound_applied(tmp_path: Path) -> None:
    clock = Clock()
    with CellStore.open(tmp_path / "cell.db", clock=clock) as store:
        # Nothing ended yet: the store's clock, which the first end stamp keeps as its floor when the clock steps back.
        bound = store.part_installs(since=T0 - timedelta(hours=1), until=FAR).until
        assert bound == T0
        clock.step(-60)
        first = run(store, clock, "G-1")
        page = store.part_installs(since=bound, until=FAR)
        assert [i.record.id for i in page.installs] == [first] and page.installs[0].ended_at == T0
        clock.step(60)
        run(store, clock, "G-2")
        latest = store.cycle(2).finished_at
        assert latest is not None and store.cycle(first).finished_at == T0 - timedelta(seconds=59.5)
        page = store.part_installs(since=T0 - timedelta(hours=1), until=FAR)
        assert [i.record.id for i in page.installs] == [first, 2] and page.until == latest + US
        assert store.part_installs(since=T0 - timedelta(hours=1), until=T0).until == T0  # as asked, before the latest
        ahead = T0 + timedelta(hours=1)  # a since ahead of every end (the MES's clock ahead): empty, not inverted
        page = store.part_installs(since=ahead, until=FAR)
        assert page.installs == () and page.until == ahead
        with pytest.raises(ValueError, match="must be later than since"):
            store.part_installs(since=ahead, until=ahead)
        assert store.part_installs(since=T0).until is None  # no until asked of the store: an open window, as before


def test_retention_deleting_the_latest_end_does_not_move_end_stamps_back(tmp_path: Path) -> None:
    path, clock = tmp_path / "cell.db", Clock()
    with CellStore.open(path, clock=clock) as store:
        run(store, clock, "G-1")
        bound = store.part_installs(since=T0 - timedelta(days=1), until=FAR).until
        assert bound is not None
        ids, _ = store.prune_cycles(created_before=FAR)
        assert ids == [1]
        clock.step(-3600)
        second = run(store, clock, "G-2")
        assert [i.record.id for i in store.part_installs(since=bound, until=FAR).installs] == [second]
    assert [r[0] for r in ended(path)] == [second]


ROW = ("INSERT INTO cycles (id, idempotency_scope, idempotency_key, recipe, part_id, source, actor, state, created_at, "
       "finished_at, interrupted_found_at) VALUES (?, 't', ?, 'side-window', ?, 't', 't', ?, ?, ?, ?)")  # fmt: skip


def test_upgrade_stamps_ended_cycles_with_the_time_their_window_was_on(tmp_path: Path) -> None:
    path = tmp_path / "cell.db"

    def t(minutes: int) -> str:
        return (T0 + timedelta(minutes=minutes)).isoformat(timespec="microseconds")

    conn = sqlite3.connect(path, isolation_level=None)
    assert schema.migrate(conn, schema.MIGRATIONS[:9]) == (0, 9)
    conn.execute(ROW, (1, "a", "done", "done", t(0), t(1), None))
    conn.execute(ROW, (2, "b", "interrupted", "interrupted", t(0), None, t(30)))
    conn.execute(ROW, (3, "c", "failed", "failed", t(0), t(2), None))
    conn.execute(ROW, (4, "d", "resumed", "running", t(0), None, t(31)))  # resumed after an interruption: not ended
    conn.close()
    clock = Clock()  # the upgraded cell starts on a clock behind the latest end
    with CellStore.open(path, clock=clock) as store:
        assert store.upgrade is not None and store.upgrade.kept_copy.is_file()
        store.complete_cycle(4, result={"ok": True})
    with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as peer:
        assert peer.execute("PRAGMA user_version").fetchone()[0] == len(schema.MIGRATIONS) >= 10
        rows = dict(peer.execute("SELECT id, ended_at FROM cycles").fetchall())
        mark = peer.execute("SELECT ended_at FROM cycle_end_mark").fetchall()
    assert rows == {1: t(1), 2: t(30), 3: t(2), 4: (T0 + timedelta(minutes=30) + US).isoformat()}, rows
    assert mark == [(rows[4],)]


def test_an_install_after_the_upgrade_and_a_clock_step_back_is_in_the_next_export(tmp_path: Path) -> None:
    """A release before end stamps gave out its clock as the export's bound (06:10), which the MES passes on as its next
    ``since``; the upgrade at 06:15 starts the end stamps there, so an install after NTP steps the clock back to 06:05
    is still in the MES's next window (it was stamped 06:06, before that ``since``, and never exported)."""
    path = tmp_path / "cell.db"
    conn = sqlite3.connect(path, isolation_level=None)
    assert schema.migrate(conn, schema.MIGRATIONS[:9]) == (0, 9)
    end = (T0 + timedelta(seconds=0.5)).isoformat(timespec="microseconds")
    conn.execute(ROW, (1, "G-1", "G-1", "done", T0.isoformat(timespec="microseconds"), end, None))
    conn.close()
    clock = Clock()
    clock.step(15 * 60)  # the service restarts on the new release at 06:15
    with CellStore.open(path, clock=clock) as store:
        assert store.upgrade is not None and store.upgrade.from_version == 9
        mes = Mes(store, lambda: FAR, T0 + timedelta(minutes=10))  # the old release's last bound: its clock then
        clock.step(-10 * 60)  # NTP steps the clock back to 06:05
        run(store, clock, "G-2")
        mes.export()
    assert [r[0] for r in ended(path)] == [1, 2] and mes.got == [2] and mes.outside == []


def test_a_clock_far_ahead_at_the_upgrade_delays_the_exports_a_day_at_most(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The upgrade starts once on a clock a year ahead (a year typed wrong), set right minutes later; an MES exports
    hourly with its own clock as ``until``. Its end stamps start no more than a day past the store's newest record, so
    every install of the week is listed, the first ones a day late at most (they were all a year ahead)."""
    path = tmp_path / "cell.db"
    conn = sqlite3.connect(path, isolation_level=None)
    assert schema.migrate(conn, schema.MIGRATIONS[:9]) == (0, 9)
    conn.execute(ROW, (1, "G-0", "G-0", "done", T0.isoformat(timespec="microseconds"),
                       (T0 + timedelta(seconds=1)).isoformat(timespec="microseconds"), None))  # fmt: skip
    conn.close()
    clock = Clock()
    clock.step(365 * 86400)
    with caplog.at_level(logging.WARNING, logger="cellctl.store.upgrade"), CellStore.open(path, clock=clock) as store:
        assert store.upgrade is not None
    assert "365.0 days past the store's newest record" in caplog.text and "check the clock" in caplog.text
    clock.step(-365 * 86400 + 300)
    with CellStore.open(path, clock=clock) as store:
        mes = Mes(store, clock, T0 + timedelta(seconds=10))
        ids, listed_at = [], {}
        for hour in range(7 * 24):
            ids.append(run(store, clock, f"G-{hour + 1}"))
            clock.step(3600 - 1)
            mes.export()
            listed_at.update({i: clock.now for i in mes.got if i not in listed_at})
    assert sorted(mes.got) == ids and mes.outside == []
    ends = {i: datetime.fromisoformat(f) for i, _, f in ended(path)}  # finished_at: the (right) clock's end
    assert max(listed_at[i] - ends[i] for i in ids) <= timedelta(days=1, hours=1)
