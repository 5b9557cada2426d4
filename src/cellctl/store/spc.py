"""The closed-loop offset in the store: its latest state and one history row per update.

Migrations 4 and 7 of :mod:`cellctl.store.schema`. The state (``spc_state``, one row per recipe) is
the loop's JSON as :func:`cellctl.quality.spc_state.state_to_dict` makes it; the store keeps plain
values and never imports the loop. The cell keeps each recipe's loop under the recipe's name; None
(``''``, history NULL) is the loop kept before that, which :meth:`SpcRows.spc_states` hands to the
configured first recipe once (:data:`cellctl.store.schema.NAME_THE_FIRST_RECIPES_LOOP`).
:meth:`SpcRows.save_spc` writes the state and its history row in one transaction, so after a restart
the state reloaded is the one the last row describes, and a cycle can feed the loop once only (a unique index on the history's cycle id).

History rows are pruned with their cycles (:meth:`cellctl.store.retention.RetentionRows.prune_cycles`)
and by age and count (:meth:`SpcRows.prune_spc_history`, which also covers rows without a cycle,
e.g. resets). The state is never pruned: it is the offset the next install takes.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from cellctl.store.connection import Database, from_json, need, to_json, ts
from cellctl.store.records import StoreError
from cellctl.store.schema import NAME_THE_FIRST_RECIPES_LOOP

ENTRY_KEYS = frozenset({"cycle_id", "calibration_version", "events", "excluded", "u", "estimate", "offset", "drifting"})
"""The keys of a history entry (:meth:`cellctl.quality.spc_state.SpcRecord.as_entry`)."""

ALL_RECIPES = object()
"""``spc_history(recipe=ALL_RECIPES)``: the rows of every recipe's loop."""


class SpcDuplicateCycle(StoreError):
    """The cycle already fed the loop: nothing was written."""


@dataclass(frozen=True)
class SpcHistoryRow:
    """One update of the loop: the uncompensated deviation ``u`` (None when excluded before it was
    formed), the estimate and the offset for the next install after it, by axis."""

    id: int
    recorded_at: datetime
    cycle_id: int | None
    calibration_version: str | None
    events: tuple[str, ...]
    excluded: str | None
    u: Mapping[str, float] | None
    estimate: Mapping[str, float | None]
    offset: Mapping[str, float]
    drifting: tuple[str, ...]
    recipe: str | None = None  # None: kept unnamed, before the loops were named (the first recipe's)


def _check_entry(entry: Mapping[str, Any]) -> None:
    keys = set(entry)
    if keys != ENTRY_KEYS:
        missing, extra = sorted(ENTRY_KEYS - keys), sorted(keys - ENTRY_KEYS)
        raise ValueError(f"an SPC history entry needs exactly {sorted(ENTRY_KEYS)}: missing {missing}, unknown {extra}")
    cid = entry["cycle_id"]
    if cid is not None and (isinstance(cid, bool) or not isinstance(cid, int)):
        raise ValueError(f"an SPC history entry's cycle_id must be an integer or None, got {cid!r}")


class SpcRows(Database):
    """The closed-loop offset methods of :class:`cellctl.store.db.CellStore`."""

    def save_spc(
        self, state: Mapping[str, Any], entry: Mapping[str, Any] | None = None, *, at: datetime | None = None,
        recipe: str | None = None,
    ) -> int | None:
        """Replace ``recipe``'s loop state and append its history ``entry`` (see :data:`ENTRY_KEYS`), in one
        transaction. Returns the history row's id (None without an entry). A cycle id already in the
        history raises :class:`SpcDuplicateCycle` and writes nothing."""
        state_json = to_json("SPC state", dict(state))
        when = ts(at or self._clock())
        with self._tx() as c:
            row_id: int | None = None
            if entry is not None:
                _check_entry(entry)
                try:
                    cur = c.execute(
                        "INSERT INTO spc_history (recorded_at, cycle_id, calibration_version, events_json, excluded, "
                        "u_json, estimate_json, offset_json, drifting_json, recipe) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                        (
                            when, entry["cycle_id"],
                            None if entry["calibration_version"] is None else str(entry["calibration_version"]),
                            to_json("SPC events", list(entry["events"])), entry["excluded"],
                            None if entry["u"] is None else to_json("SPC deviation", dict(entry["u"])),
                            to_json("SPC estimate", dict(entry["estimate"])),
                            to_json("SPC offset", dict(entry["offset"])),
                            to_json("SPC drifting axes", list(entry["drifting"])), recipe,
                        ),
                    )  # fmt: skip
                except sqlite3.IntegrityError as err:
                    if "spc_history.cycle_id" not in str(err):
                        raise
                    raise SpcDuplicateCycle(
                        f"cycle {entry['cycle_id']} already fed the SPC loop; a result is counted once"
                    ) from None
                row_id = int(cur.lastrowid or 0)
            c.execute(
                "INSERT INTO spc_state (recipe, state_json, updated_at, history_id) VALUES (?, ?, ?, ?) "
                "ON CONFLICT (recipe) DO UPDATE SET state_json = excluded.state_json, updated_at = excluded.updated_at, "
                "history_id = excluded.history_id",
                (_key(recipe), state_json, when, row_id),
            )
        return row_id

    def spc_state(self, recipe: str | None = None) -> dict[str, Any] | None:
        """``recipe``'s loop as last saved (its JSON values), None before its first save."""
        r = self._conn.execute("SELECT state_json FROM spc_state WHERE recipe = ?", (_key(recipe),)).fetchone()
        return None if r is None else dict(json.loads(r[0]))

    def spc_states(self, *, first_recipe: str | None = None) -> dict[str | None, dict[str, Any]]:
        """Every recipe's loop as last saved, by recipe's name (None: a loop kept unnamed, the first recipe's).

        ``first_recipe``: the name of the recipe configured first; the unnamed loop and its history
        become that recipe's first, in one transaction (:data:`~cellctl.store.schema.NAME_THE_FIRST_RECIPES_LOOP`).
        """
        if first_recipe is not None:
            need("first_recipe", first_recipe)
            with self._tx() as c:
                for sql in NAME_THE_FIRST_RECIPES_LOOP:
                    c.execute(sql, {"name": first_recipe} if ":name" in sql else {})
        rows = self._conn.execute("SELECT recipe, state_json FROM spc_state ORDER BY recipe").fetchall()
        return {(r[0] or None): dict(json.loads(r[1])) for r in rows}

    def spc_history(
        self, *, limit: int = 200, before_id: int | None = None, recipe: str | None | object = ALL_RECIPES
    ) -> list[SpcHistoryRow]:
        """The newest ``limit`` rows (older than ``before_id`` to page back) of one recipe's loop or of all
        (:data:`ALL_RECIPES`), oldest first (a chart's order)."""
        if limit < 1:
            raise ValueError("limit must be at least 1")
        where: list[str] = []
        args: tuple[Any, ...] = ()
        if before_id is not None:
            where.append("id < ?")
            args += (int(before_id),)
        if recipe is not ALL_RECIPES:
            where.append("recipe IS ?")
            args += (recipe,)
        sql = f"SELECT {_COLUMNS} FROM spc_history" + (f" WHERE {' AND '.join(where)}" if where else "")
        rows = self._conn.execute(f"{sql} ORDER BY id DESC LIMIT ?", (*args, int(limit))).fetchall()
        return [_row(r) for r in reversed(rows)]

    def prune_spc_history(self, *, recorded_before: datetime | None = None, keep_last: int | None = None) -> int:
        """Delete history rows recorded before the cutoff and/or all but the newest ``keep_last``.
        Returns how many. The state is never touched."""
        if keep_last is not None and keep_last < 0:
            raise ValueError("keep_last must be 0 or more")
        n = 0
        with self._tx() as c:
            if recorded_before is not None:
                n += c.execute("DELETE FROM spc_history WHERE recorded_at < ?", (ts(recorded_before),)).rowcount
            if keep_last is not None:
                n += c.execute(
                    "DELETE FROM spc_history WHERE id NOT IN (SELECT id FROM spc_history ORDER BY id DESC LIMIT ?)",
                    (int(keep_last),),
                ).rowcount
        return n


_COLUMNS = (
    "id, recorded_at, cycle_id, calibration_version, events_json, excluded, u_json, estimate_json, offset_json, "
    "drifting_json, recipe"
)


def _key(recipe: str | None) -> str:
    """``spc_state``'s key: the recipe's name; '' for None, the loop kept unnamed."""
    if recipe == "":
        raise ValueError("a recipe's name cannot be empty; None names the cell's first recipe")
    return recipe or ""


def _row(r: Sequence[Any]) -> SpcHistoryRow:
    return SpcHistoryRow(
        id=int(r[0]),
        recorded_at=datetime.fromisoformat(r[1]),
        cycle_id=None if r[2] is None else int(r[2]),
        calibration_version=r[3],
        events=tuple(from_json(r[4])),
        excluded=r[5],
        u=from_json(r[6]),
        estimate=from_json(r[7]),
        offset=from_json(r[8]),
        drifting=tuple(from_json(r[9])),
        recipe=r[10],
    )
