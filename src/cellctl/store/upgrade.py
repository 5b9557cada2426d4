"""A store written by an earlier release: the copy kept before its migration, and where a rollback finds it.

A migration is one way: the release before it refuses the migrated file (``SchemaTooNew``). So before the first
pending migration of a store that holds data, the database is copied, whole and consistent (SQLite's online backup,
the WAL's last commits included), to ``<file>.schema<N>-<UTC time>.bak`` beside it; without that copy nothing is
migrated. To go back to the release that wrote schema N: stop the service, install that release and put the copy in
place of the file (README, "Backup, upgrade and rollback"). The copies are never deleted by the cell.
"""

from __future__ import annotations

import logging
import sqlite3
from contextlib import closing
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path

from cellctl.store.records import StoreError
from cellctl.store.schema import MIGRATIONS, V10_END_STAMP, migrate, schema_version

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StoreUpgrade:
    """A migration done on opening: the schema versions before and after, and the copy kept of the file before it."""

    path: Path
    from_version: int
    to_version: int
    kept_copy: Path

    def summary(self) -> str:
        return (
            f"store {self.path} migrated from schema {self.from_version} to {self.to_version}: a release that knows "
            f"only schema {self.from_version} cannot open it any more; the store as it was is kept in {self.kept_copy} "
            "for a rollback (README, Backup, upgrade and rollback)"
        )


def kept_copy_path(path: Path, version: int, now: datetime) -> Path:
    """Where the copy of ``path`` at schema ``version`` is kept: beside it, named by the version and the UTC time."""
    return path.with_name(f"{path.name}.schema{version}-{now.strftime('%Y%m%dT%H%M%SZ')}.bak")


def copies_for_rollback(path: Path, version: int) -> list[Path]:
    """The copies kept of ``path`` at schema ``version`` (the store before an upgrade from it), oldest first."""
    return sorted(path.parent.glob(f"{path.name}.schema{version}-*.bak"))


def migrate_keeping_a_copy(conn: sqlite3.Connection, path: Path, now: datetime) -> StoreUpgrade | None:
    """Apply the pending migrations to the open database ``conn`` of file ``path``; a store at an earlier schema
    (not a new, empty one) is first copied (:func:`kept_copy_path`). Returns what was done, None if nothing was."""
    before = schema_version(conn)
    if not 0 < before < len(MIGRATIONS):
        migrate(conn)  # a new file, one already current, or one too new (SchemaTooNew)
        return None
    copy = kept_copy_path(path, before, now)
    try:
        with closing(sqlite3.connect(copy)) as target:
            conn.backup(target)
    except sqlite3.Error as err:
        copy.unlink(missing_ok=True)
        raise StoreError(
            f"[store] path {path}: schema {before} needs migrating to {len(MIGRATIONS)}, and the copy kept for a "
            f"rollback ({copy}) could not be written ({err}): free space in {path.parent} (the copy is as large as "
            "the file), then start again; nothing was migrated"
        ) from None
    floor = now if before >= END_STAMP_VERSION else _end_stamp_floor(conn, now)
    _, after = migrate(conn, _end_stamps_floored(floor))
    return StoreUpgrade(path, before, after, copy)


END_STAMP_VERSION = MIGRATIONS.index(V10_END_STAMP) + 1
"""The schema whose migration gave cycles their end stamp (``ended_at``)."""
FLOOR_PAST_NEWEST = timedelta(days=1)
"""The end stamps' floor at that upgrade is the clock, but no later than this past the newest time the store holds."""


def _end_stamp_floor(conn: sqlite3.Connection, now: datetime) -> datetime:
    """Where the end stamps start after the upgrade that brings them: the clock (the older release's export bounds went
    up to its clock), but no more than a day past the newest time the store holds (a cycle, an audit entry), so a
    clock far ahead at the upgrade (a year typed wrong) does not stamp every later end that far ahead."""
    row = conn.execute("SELECT MAX(t) FROM (SELECT MAX(created_at) AS t FROM cycles UNION ALL SELECT MAX(finished_at) "
                       "FROM cycles UNION ALL SELECT MAX(at) FROM audit_log)").fetchone()  # fmt: skip
    newest = None if row is None or row[0] is None else datetime.fromisoformat(row[0])
    if newest is None or now <= newest + FLOOR_PAST_NEWEST:
        return now
    log.warning("store upgrade: the clock (%s) is %.1f days past the store's newest record (%s): its end stamps start at "
                "%s; check the clock", now.isoformat(), (now - newest) / timedelta(days=1), newest.isoformat(),
                (newest + FLOOR_PAST_NEWEST).isoformat())  # fmt: skip
    return newest + FLOOR_PAST_NEWEST


def _end_stamps_floored(now: datetime) -> list[str]:
    """MIGRATIONS, with the end stamps' floor raised to ``now`` (:func:`_end_stamp_floor`) in the migration that brings
    them: a release before them gave out export bounds up to its clock (an MES passes one on as its next ``since``), so
    an end stamped earlier, once the clock stepped back, would fall before a window already exported, never listed."""
    at = now.astimezone(timezone.utc).isoformat(timespec="microseconds")  # as the store keeps times
    floored = list(MIGRATIONS)
    floored[END_STAMP_VERSION - 1] += (
        f"UPDATE cycle_end_mark SET ended_at = '{at}' WHERE id = 1 AND (ended_at IS NULL OR ended_at < '{at}');\n"
    )
    return floored
