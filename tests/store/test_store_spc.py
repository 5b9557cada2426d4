"""The closed-loop offset in the store: state and history saved together, a restart that neither loses
the offset nor counts a result twice, the history for the dashboard's chart, and its retention."""

from __future__ import annotations

import json
import sqlite3
import threading
from dataclasses import replace
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
from spc_support import make_loop, simulate_loop

from cellctl.quality import (
    AXES,
    Exclusion,
    SpcEvent,
    SpcLoop,
    SpcState,
    SpcUpdate,
    state_from_dict,
    state_to_dict,
)
from cellctl.store import (
    AsyncCellStore,
    CellStore,
    CycleRequest,
    SpcDuplicateCycle,
    schema,
)
from cellctl.store.spc import ENTRY_KEYS

T0 = datetime(2026, 3, 1, 8, 0, tzinfo=timezone.utc)
BIAS = {"dx_mm": 0.12, "dy_mm": -0.08, "drx_deg": 0.03}
SIGMA = (0.03, 0.005)


class Clock:
    def __init__(self) -> None:
        self.t = T0

    def __call__(self) -> datetime:
        return self.t


def save(store: CellStore, up: SpcUpdate) -> int | None:
    """What the lead's cycle does after each update."""
    return store.save_spc(state_to_dict(up.state), None if up.record is None else up.record.as_entry())


def load(store: CellStore) -> SpcState:
    d = store.spc_state()
    return SpcState() if d is None else state_from_dict(d)


def test_state_and_history_round_trip_through_a_restart(tmp_path: Path) -> None:
    run = simulate_loop(BIAS, SIGMA, 30, seed=1, spikes={20: {"dy_mm": 0.3}}, version=3)
    with CellStore.open(tmp_path / "c.db") as store:
        assert store.spc_state() is None and store.spc_history() == []
        ids = [save(store, up) for up in run.updates]
    with CellStore.open(tmp_path / "c.db") as store:  # the restart
        again = load(store)
        assert again == run.state  # every figure, count, warm-up and timestamp
        assert make_loop().offset(again, 3) == make_loop().offset(run.state, 3) != dict.fromkeys(AXES, 0.0)
        rows = store.spc_history(limit=1000)
    assert [r.id for r in rows] == ids and [r.cycle_id for r in rows] == list(range(1, 31))
    for row, up in zip(rows, run.updates):
        assert up.record is not None
        assert row.u == up.record.u and row.estimate == up.record.estimate and row.offset == up.record.offset
        assert row.calibration_version == "3" and row.drifting == ()
    assert rows[4].events == (SpcEvent.ESTIMATE_STARTED.value,) and rows[4].estimate["dx_mm"] is not None
    assert rows[20].excluded == Exclusion.OUTLIER.value and rows[0].excluded is None


def test_a_restart_mid_stream_continues_exactly_as_without_it(tmp_path: Path) -> None:
    """Never loses the offset, never applies it twice: the offset is a function of the estimate of the
    uncompensated deviation, reloaded as saved."""
    loop = make_loop()
    straight = simulate_loop(BIAS, SIGMA, 60, seed=2, loop=loop)
    first = simulate_loop(BIAS, SIGMA, 60, seed=2, loop=loop)  # the same cell, stopped after 25
    with CellStore.open(tmp_path / "c.db") as store:
        for up in first.updates[:25]:
            save(store, up)
    with CellStore.open(tmp_path / "c.db") as store:
        state = load(store)
        assert loop.offset(state, "1") == first.applied[25]  # what result 26 was installed with
        for i in range(25, 60):
            up = loop.update(state, first.measured[i], calibration_version="1", cycle_id=i + 1)
            save(store, up)
            state = up.state
        assert state == straight.state and load(store) == straight.state
        assert len(store.spc_history(limit=100)) == 60


def test_a_result_already_counted_is_refused_by_the_loop_and_the_store(tmp_path: Path) -> None:
    loop = make_loop()
    run = simulate_loop(BIAS, SIGMA, 10, seed=3, loop=loop)
    with CellStore.open(tmp_path / "c.db") as store:
        for up in run.updates:
            save(store, up)
        state = load(store)
        # the lead re-feeds cycle 10 after a crash: the loop changes nothing and says so
        up = loop.update(state, run.measured[-1], calibration_version="1", cycle_id=10)
        assert up.excluded == Exclusion.DUPLICATE and up.record is None and up.state == state
        # and the store refuses a second row for a cycle, writing nothing (not even the state)
        forged = loop.update(replace(state, last_cycle_id=None), run.measured[-1], calibration_version="1", cycle_id=10)
        assert forged.record is not None
        with pytest.raises(SpcDuplicateCycle, match="cycle 10 already fed the SPC loop"):
            save(store, forged)
        assert load(store) == state and len(store.spc_history()) == 10


def test_resets_are_history_rows_without_a_cycle(tmp_path: Path) -> None:
    loop = make_loop()
    run = simulate_loop({"dx_mm": 0.4}, SIGMA, 12, seed=4, loop=loop)
    clock = Clock()
    with CellStore.open(tmp_path / "c.db", clock=clock) as store:
        for up in run.updates:
            save(store, up)
        reset = loop.reset(load(store), at=clock())
        save(store, reset)
        last = store.spc_history(limit=1)[0]
        assert (last.cycle_id, last.events, last.recorded_at) == (None, (SpcEvent.RESET_OPERATOR.value,), T0)
        assert load(store).reset_at == T0 and load(store).drifting == ()
        assert any(r.drifting == ("dx_mm",) for r in store.spc_history())


def test_history_pages_back_oldest_first(tmp_path: Path) -> None:
    run = simulate_loop(BIAS, SIGMA, 12, seed=5)
    with CellStore.open(tmp_path / "c.db") as store:
        for up in run.updates:
            save(store, up)
        newest = store.spc_history(limit=5)
        assert [r.cycle_id for r in newest] == [8, 9, 10, 11, 12]
        older = store.spc_history(limit=5, before_id=newest[0].id)
        assert [r.cycle_id for r in older] == [3, 4, 5, 6, 7]
        with pytest.raises(ValueError, match="limit"):
            store.spc_history(limit=0)


def test_an_entry_must_be_complete_and_the_state_finite(tmp_path: Path) -> None:
    with CellStore.open(tmp_path / "c.db") as store:
        state = state_to_dict(SpcState())
        with pytest.raises(ValueError, match=r"missing \['u'\]"):
            store.save_spc(state, {k: None for k in ENTRY_KEYS if k != "u"})
        with pytest.raises(ValueError, match="NaN or infinity"):
            store.save_spc({**state, "n_samples": float("nan")})
        assert store.save_spc(state) is None and load(store) == SpcState()
        with pytest.raises(ValueError, match="format"):
            state_from_dict({**state, "format": 99})


# -- retention --------------------------------------------------------------------------------------


def _cycle(store: CellStore, n: int) -> int:
    cid = store.submit_cycle(CycleRequest("side-window-A", f"P-{n}"), scope="t", key=f"k-{n}", actor="t").cycle.id
    store.start_cycle(cid)
    store.complete_cycle(cid, result={"ok": True})
    return cid


def test_history_rows_go_with_their_cycles_and_by_age_and_count_but_the_state_stays(tmp_path: Path) -> None:
    clock = Clock()
    loop = make_loop()
    with CellStore.open(tmp_path / "c.db", clock=clock) as store:
        state = SpcState()
        cids = []
        for n in range(8):
            clock.t = T0 + timedelta(days=n * 100)
            cid = _cycle(store, n)
            cids.append(cid)
            up = loop.update(state, dict.fromkeys(AXES, 0.1 if n % 2 else 0.08), calibration_version=1, cycle_id=cid, at=clock())
            save(store, up)
            state = up.state
        save(store, loop.reset(state, at=clock()))  # a row without a cycle
        kept_state = store.spc_state()
        # cycle retention takes the cycles' rows along
        ids, _ = store.prune_cycles(created_before=T0 + timedelta(days=150))
        assert ids == cids[:2]
        assert [r.cycle_id for r in store.spc_history()] == [*cids[2:], None]
        # by age (rows of any kind), then by count
        assert store.prune_spc_history(recorded_before=T0 + timedelta(days=350)) == 2
        assert [r.cycle_id for r in store.spc_history()] == [*cids[4:], None]
        assert store.prune_spc_history(keep_last=2) == 3
        assert [r.cycle_id for r in store.spc_history()] == [cids[7], None]
        assert store.spc_state() == kept_state  # the offset is never pruned
        with pytest.raises(ValueError, match="keep_last"):
            store.prune_spc_history(keep_last=-1)


def test_migration_4_adds_the_spc_tables_to_an_existing_database(tmp_path: Path) -> None:
    path = tmp_path / "old.db"
    raw = sqlite3.connect(path, isolation_level=None)
    schema.migrate(raw, schema.MIGRATIONS[:3])  # a database written before the loop existed
    raw.close()
    with CellStore.open(path) as store:
        assert store.info().schema_version == len(schema.MIGRATIONS) >= 4
        tables = {r[0] for r in store._conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        assert {"spc_state", "spc_history"} <= tables
        assert store.spc_state() is None


def test_each_recipe_keeps_its_own_state_and_history(tmp_path: Path) -> None:
    first = simulate_loop(BIAS, SIGMA, 6, seed=1, version=3)
    door = simulate_loop({"dx_mm": -0.2}, SIGMA, 4, seed=2, version=3, first_cycle=100)
    with CellStore.open(tmp_path / "c.db") as store:
        for up in first.updates:
            save(store, up)
        for up in door.updates:
            store.save_spc(state_to_dict(up.state), up.record.as_entry(), recipe="door-window")
    with CellStore.open(tmp_path / "c.db") as store:  # a restart
        assert load(store) == first.updates[-1].state
        assert state_from_dict(store.spc_state("door-window")) == door.updates[-1].state
        assert set(store.spc_states()) == {None, "door-window"}
        assert [r.cycle_id for r in store.spc_history(recipe="door-window")] == [100, 101, 102, 103]
        assert [r.recipe for r in store.spc_history(recipe=None)] == [None] * 6  # the first recipe's
        assert len(store.spc_history()) == 10  # every loop's
        with pytest.raises(ValueError, match="None names the cell's first recipe"):
            store.spc_state("")


def test_migration_7_gives_the_loop_of_before_to_the_first_recipe(tmp_path: Path) -> None:
    path = tmp_path / "old.db"
    raw = sqlite3.connect(path, isolation_level=None)
    schema.migrate(raw, schema.MIGRATIONS[:6])  # one loop for the cell, as before recipes had their own
    raw.close()
    run = simulate_loop(BIAS, SIGMA, 8, seed=4, version=3)
    with sqlite3.connect(path, isolation_level=None) as raw:
        raw.execute(
            "INSERT INTO spc_state (id, state_json, updated_at, history_id) VALUES (1, ?, ?, NULL)",
            (json.dumps(state_to_dict(run.updates[-1].state)), T0.isoformat()),
        )
    with CellStore.open(path) as store:
        assert store.info().schema_version == len(schema.MIGRATIONS) >= 7
        assert load(store) == run.updates[-1].state and set(store.spc_states()) == {None}
        assert store.spc_state("door-window") is None


# -- from asyncio -----------------------------------------------------------------------------------


async def test_the_async_store_runs_the_spc_calls_on_its_thread(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    threads: set[str] = set()
    original = CellStore.save_spc

    def spy(self: CellStore, *a: object, **kw: object) -> object:
        threads.add(threading.current_thread().name)
        return original(self, *a, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(CellStore, "save_spc", spy)
    loop: SpcLoop = make_loop()
    run = simulate_loop(BIAS, SIGMA, 8, seed=6, loop=loop)
    store = await AsyncCellStore.open(tmp_path / "c.db")
    for up in run.updates:
        assert up.record is not None
        await store.save_spc(state_to_dict(up.state), up.record.as_entry())
    assert len(threads) == 1 and next(iter(threads)).startswith("cellctl-store")
    d = await store.spc_state()
    assert d is not None and state_from_dict(d) == run.state
    assert len(await store.spc_history(limit=3)) == 3
    assert await store.prune_spc_history(keep_last=5) == 3
    await store.close()
