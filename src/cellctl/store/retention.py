"""Retention in the store: what is kept, what was pruned, and the database's own size.

Migration 3 of :mod:`cellctl.store.schema` lets an image reference say that its file was pruned
(when and why), so a record keeps answering for an image that is gone. The queries here are what
the retention task (:mod:`cellctl.service.retention`) runs on the store's thread:

- images: the references still kept (with whether their cycle is still queued or running, whose
  images are never pruned), marking references pruned, and which files belong only to pruned
  references (left on disk by a crash between the mark and the unlink). A reference marked
  :data:`MISSING_REASON` says only that its file was not there when retention looked: such a file
  is never a leftover to delete, and when it is back its reference is kept again
  (:meth:`RetentionRows.restore_missing_images`);
- cycle records that ended before a cutoff (on their end stamp, which a clock set back does not lower), deleted with their steps, image references, idempotency
  keys and closed-loop history rows, in batches so no single transaction holds the write lock for long
  (the loop's history is also pruned by age and count alone: :meth:`cellctl.store.spc.SpcRows.prune_spc_history`);
  the finished keys of no cycle (a refused request's) go after the same cutoff, by their own time stamp.
  A cycle whose MQTT result was never queued (above the results' high-water mark, once MQTT
  publication was set up) is kept while publication is configured; otherwise its deletion is
  counted as a dropped result, which the next MQTT connection reports to the plant (``outbox/dropped``);
- alarm records older than a cutoff: inactive and acknowledged ones only, and none of a cycle whose record is
  kept (a part record keeps its alarms as long as it is kept; an alarm nobody acknowledged is kept);
- the database's size (pages used, free pages, per-table bytes where SQLite has ``dbstat``).

The audit log is never pruned: it is append-only (triggers refuse deletes) and hash-chained from
its first entry, it says who commanded what, and it is small beside the images.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from cellctl.store.connection import Database, ts

FINISHED_CYCLE_STATES = ("done", "failed", "interrupted")
MISSING_REASON = "file missing on disk when retention looked"  # marked by a look, not by deleting the file


@dataclass(frozen=True)
class KeptImage:
    """An image reference whose file has not been pruned."""

    id: int
    cycle_id: int
    uri: str
    created_at: datetime  # aged from: when it was made, or its cycle's end stamp where that is later (a clock set back)
    cycle_active: bool  # its cycle is queued or running: never pruned


@dataclass(frozen=True)
class DatabaseSize:
    """The database's pages (``used_bytes`` excludes the free pages SQLite reuses) and, where SQLite
    has the ``dbstat`` table, the bytes of each table with its indexes."""

    page_size: int
    page_count: int
    freelist_count: int
    tables: dict[str, int] | None = None

    @property
    def used_bytes(self) -> int:
        return (self.page_count - self.freelist_count) * self.page_size

    @property
    def total_bytes(self) -> int:
        return self.page_count * self.page_size


def _chunks(items: Sequence[Any], n: int = 500) -> Iterable[Sequence[Any]]:
    for i in range(0, len(items), n):
        yield items[i : i + n]


def _count_unpublished(c: Any, n: int) -> None:
    """``n`` deleted cycles' results were never queued for MQTT: count them as dropped results, to report."""
    if n:
        c.execute(
            "UPDATE mqtt_outbox_state SET dropped_total = dropped_total + ?, dropped_results = dropped_results + ?, "
            "unreported_dropped = unreported_dropped + ?, unreported_dropped_results = unreported_dropped_results + ? "
            "WHERE id = 1",
            (n, n, n, n),
        )


class RetentionRows(Database):
    """The retention methods of :class:`cellctl.store.db.CellStore`."""

    # -- images -------------------------------------------------------------------------------

    def kept_images(self) -> list[KeptImage]:
        """Every image reference not yet pruned, oldest first; each aged from the later of its own time and its cycle's end
        stamp (which never goes back: an image made while the clock was set back is not aged by that clock)."""
        rows = self._conn.execute(
            "SELECT i.id, i.cycle_id, i.uri, i.created_at, c.ended_at, c.state IN ('queued', 'running') "
            "FROM cycle_images i JOIN cycles c ON c.id = i.cycle_id WHERE i.pruned_at IS NULL ORDER BY i.id"
        ).fetchall()
        return [
            KeptImage(int(r[0]), int(r[1]), r[2], max(datetime.fromisoformat(r[3]), datetime.fromisoformat(r[4] or r[3])), bool(r[5])) for r in rows
        ]

    def mark_images_pruned(self, uris: Sequence[str], *, reason: str, at: datetime | None = None) -> int:
        """Say that the files ``uris`` are gone and why; every kept reference to them is marked. Returns how many."""
        if not reason.strip():
            raise ValueError("reason must say why the images were pruned")
        when = ts(at or self._clock())
        n = 0
        with self._tx() as c:
            for chunk in _chunks(list(dict.fromkeys(uris))):
                marks = ",".join("?" * len(chunk))
                n += c.execute(
                    f"UPDATE cycle_images SET pruned_at = ?, pruned_reason = ? WHERE pruned_at IS NULL AND uri IN ({marks})",
                    (when, reason, *chunk),
                ).rowcount
        return n

    def pruned_only(self, uris: Sequence[str]) -> set[str]:
        """Of ``uris``, those every reference of which says pruned by retention deleting the file
        (their files should be gone); a reference marked :data:`MISSING_REASON` never counts."""
        out: set[str] = set()
        for chunk in _chunks(list(dict.fromkeys(uris))):
            marks = ",".join("?" * len(chunk))
            out.update(
                r[0]
                for r in self._conn.execute(
                    f"SELECT uri FROM cycle_images WHERE uri IN ({marks}) GROUP BY uri "
                    "HAVING COUNT(pruned_at) = COUNT(*) AND SUM(COALESCE(pruned_reason, '') = ?) = 0",
                    (*chunk, MISSING_REASON),
                )
            )
        return out

    def restore_missing_images(self, uris: Sequence[str]) -> list[str]:
        """The files ``uris`` are there: references marked :data:`MISSING_REASON` to them are kept
        again (not pruned). Returns the files whose references were restored."""
        out: list[str] = []
        with self._tx() as c:
            for chunk in _chunks(list(dict.fromkeys(uris))):
                marks = ",".join("?" * len(chunk))
                args = (MISSING_REASON, *chunk)
                where = f"WHERE pruned_reason = ? AND uri IN ({marks})"
                out += [r[0] for r in c.execute(f"SELECT DISTINCT uri FROM cycle_images {where}", args)]
                c.execute(f"UPDATE cycle_images SET pruned_at = NULL, pruned_reason = NULL {where}", args)
        return out

    # -- records ------------------------------------------------------------------------------

    def prune_cycles(
        self, *, created_before: datetime, batch: int = 500, keep_unpublished: bool = False
    ) -> tuple[list[int], list[str]]:
        """Delete up to ``batch`` finished cycles ended before the cutoff, oldest first, with their
        steps, image references, idempotency keys and closed-loop history rows. Returns (the ids deleted, the image files
        they still referenced: delete those too). Call again until it returns no ids.

        A cycle above the MQTT results' high-water mark (its result never queued) is kept with
        ``keep_unpublished`` (publication is configured); else its deletion counts as a dropped result.

        A cycle is aged by its end stamp ``ended_at``, which never goes back (:func:`cellctl.store.cycles.end_stamp`):
        one recorded while the wall clock was set back (a PC's dead clock battery, say) is not taken for that old
        once the clock is right again, across restarts. A finished cycle without one (none since schema 10) by
        ``created_at``."""
        cutoff = ts(created_before)
        with self._tx() as c:
            hwm = c.execute("SELECT result_hwm FROM mqtt_outbox_state WHERE id = 1").fetchone()[0]
            held = keep_unpublished and hwm is not None
            ids = [
                int(r[0])
                for r in c.execute(
                    f"SELECT id FROM cycles WHERE (ended_at < ? OR (ended_at IS NULL AND created_at < ?)) "
                    f"AND state IN {FINISHED_CYCLE_STATES} {'AND id <= ? ' if held else ''}ORDER BY id LIMIT ?",
                    (cutoff, cutoff, *((int(hwm),) if held else ()), int(batch)),
                )
            ]
            if not ids:
                return [], []
            marks = ",".join("?" * len(ids))
            uris = [
                r[0]
                for r in c.execute(
                    f"SELECT DISTINCT uri FROM cycle_images WHERE pruned_at IS NULL AND cycle_id IN ({marks})", ids
                )
            ]
            for table in ("idempotency_keys", "cycle_images", "cycle_steps", "spc_history"):
                c.execute(f"DELETE FROM {table} WHERE cycle_id IN ({marks})", ids)
            c.execute(f"DELETE FROM cycles WHERE id IN ({marks})", ids)
            _count_unpublished(c, 0 if held or hwm is None else sum(i > int(hwm) for i in ids))
            # A file that a kept reference of another cycle still names stays.
            kept = {
                u for u in uris
                if c.execute("SELECT 1 FROM cycle_images WHERE uri = ? AND pruned_at IS NULL LIMIT 1", (u,)).fetchone()
            }  # fmt: skip
        return ids, [u for u in uris if u not in kept]

    def prune_request_keys(self, *, created_before: datetime, batch: int = 500) -> int:
        """Delete up to ``batch`` finished idempotency keys of no cycle (a refused request's, a
        command's) created before the cutoff, oldest first; a cycle's key goes with its cycle
        (:meth:`prune_cycles`), an open claim stays. Returns how many; call again until 0."""
        with self._tx() as c:
            return c.execute(
                "DELETE FROM idempotency_keys WHERE rowid IN (SELECT rowid FROM idempotency_keys "
                "WHERE cycle_id IS NULL AND response_json IS NOT NULL AND created_at < ? ORDER BY created_at LIMIT ?)",
                (ts(created_before), int(batch)),
            ).rowcount

    def prune_alarms(self, *, raised_before: datetime) -> int:
        """Delete the records of alarms raised before the cutoff that are no longer active and were
        acknowledged, unless their cycle's record is still kept (its part record lists them)."""
        with self._tx() as c:
            return c.execute(
                "DELETE FROM alarms WHERE raised_at < ? AND active = 0 AND ack_at IS NOT NULL "
                "AND NOT EXISTS (SELECT 1 FROM cycles WHERE cycles.id = alarms.cycle_id)",
                (ts(raised_before),),
            ).rowcount

    def oldest_cycle(self) -> datetime | None:
        r = self._conn.execute("SELECT MIN(created_at) FROM cycles").fetchone()
        return None if r is None or r[0] is None else datetime.fromisoformat(r[0])

    # -- size ---------------------------------------------------------------------------------

    def database_size(self, *, per_table: bool = False) -> DatabaseSize:
        """Pages used and free; ``per_table`` adds each table's bytes (with its indexes) from ``dbstat``
        (a scan of the whole file: for reports, not for every status call)."""
        page_size = int(self._conn.execute("PRAGMA page_size").fetchone()[0])
        page_count = int(self._conn.execute("PRAGMA page_count").fetchone()[0])
        free = int(self._conn.execute("PRAGMA freelist_count").fetchone()[0])
        tables: dict[str, int] | None = None
        if per_table:
            try:
                rows = self._conn.execute(
                    "SELECT COALESCE(m.tbl_name, s.name), SUM(s.pgsize) FROM dbstat s "
                    "LEFT JOIN sqlite_master m ON m.name = s.name GROUP BY 1 ORDER BY 2 DESC"
                ).fetchall()
                tables = {str(r[0]): int(r[1]) for r in rows}
            except sqlite3.OperationalError:  # SQLite built without SQLITE_ENABLE_DBSTAT_VTAB
                tables = None
        return DatabaseSize(page_size, page_count, free, tables)

    def checkpoint(self) -> None:
        """Move the write-ahead log into the database file and truncate it (e.g. after a large prune)."""
        self._conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
