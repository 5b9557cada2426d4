"""The loop the store kept unnamed (schema 7: '' for "the first recipe", history NULL) becomes the configured
first recipe's by name, once; from then on a loop is found by its recipe's name, whatever the order.

Read back with sqlite3 itself (an independent peer), not only through the store.
"""

from __future__ import annotations

import json
import sqlite3
from datetime import datetime, timedelta, timezone
from pathlib import Path

from spc_support import simulate_loop

from cellctl.quality import state_from_dict, state_to_dict
from cellctl.store import CellStore, schema

T0 = datetime(2026, 3, 1, 8, 0, tzinfo=timezone.utc)


def _old_database(path: Path) -> dict[str, object]:
    """A database at schema 7 whose one loop (the side window's, then first) is kept unnamed, with 5 history rows."""
    raw = sqlite3.connect(path, isolation_level=None)
    schema.migrate(raw, schema.MIGRATIONS[:7])
    run = simulate_loop({"dx_mm": 0.12}, (0.03, 0.005), 5, seed=7, version=3)
    state = state_to_dict(run.updates[-1].state)
    with raw:
        for k, up in enumerate(run.updates):
            e = up.record.as_entry()  # type: ignore[union-attr]
            raw.execute(
                "INSERT INTO spc_history (recorded_at, cycle_id, calibration_version, events_json, estimate_json, offset_json) "
                "VALUES (?, ?, ?, '[]', ?, ?)",
                ((T0 + timedelta(minutes=k)).isoformat(), e["cycle_id"], "3", json.dumps(e["estimate"]), json.dumps(e["offset"])),
            )  # fmt: skip
        raw.execute("INSERT INTO spc_state (recipe, state_json, updated_at) VALUES ('', ?, ?)", (json.dumps(state), T0.isoformat()))
    raw.close()
    return state


def _rows(path: Path) -> tuple[list[str], list[str | None]]:
    with sqlite3.connect(path) as raw:
        states = [r[0] for r in raw.execute("SELECT recipe FROM spc_state ORDER BY recipe")]
        history = [r[0] for r in raw.execute("SELECT recipe FROM spc_history ORDER BY id")]
    return states, history


def test_the_unnamed_loop_becomes_the_first_recipes_by_name_once(tmp_path: Path) -> None:
    path = tmp_path / "cell.db"
    state = _old_database(path)
    with CellStore.open(path) as store:
        assert _rows(path) == ([""], [None] * 5)  # opening alone cannot know the first recipe's name
        loops = store.spc_states(first_recipe="side-window")
        assert set(loops) == {"side-window"} and state_from_dict(loops["side-window"]) == state_from_dict(state)
    assert _rows(path) == (["side-window"], ["side-window"] * 5)
    # the configuration now lists the door window first: the side window's loop stays the side window's
    with CellStore.open(path) as store:
        loops = store.spc_states(first_recipe="door-window")
        assert set(loops) == {"side-window"} and "door-window" not in loops
        assert [r.recipe for r in store.spc_history(recipe="side-window")] == ["side-window"] * 5
        assert store.spc_history(recipe="door-window") == []
    assert _rows(path) == (["side-window"], ["side-window"] * 5)


def test_of_two_rows_for_one_recipe_the_later_stays(tmp_path: Path) -> None:
    path = tmp_path / "cell.db"
    _old_database(path)  # the unnamed row, saved at T0
    newer = {"later": True}
    with sqlite3.connect(path) as raw:  # the named row, saved later (then an older cellctl wrote the unnamed one)
        raw.execute("INSERT INTO spc_state (recipe, state_json, updated_at) VALUES ('side-window', ?, ?)",
                    (json.dumps(newer), (T0 + timedelta(hours=1)).isoformat()))  # fmt: skip
    with CellStore.open(path) as store:
        assert store.spc_states(first_recipe="side-window") == {"side-window": newer}
    assert _rows(path)[0] == ["side-window"]
