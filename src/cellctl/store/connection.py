"""The store's one SQLite connection: opening it, write transactions, and the value conversions.

:class:`Database` owns the connection, the database path and the clock. Every repository of the
store (:mod:`~cellctl.store.cycles`, :mod:`~cellctl.store.alarms`, :mod:`~cellctl.store.audit`,
:mod:`~cellctl.store.jobs`, :mod:`~cellctl.store.retention`) is a subclass of it, and
:class:`cellctl.store.db.CellStore` inherits them all, so they share this one connection.

The connection belongs to the thread that opened it (sqlite3's default check). Every method that
changes something runs in one :meth:`Database._tx` and commits before it returns.

Conversions: timestamps are timezone-aware UTC datetimes, stored as ISO 8601 text with
microseconds (:func:`ts`); figures, requests and responses are stored as canonical JSON
(:func:`to_json`: sorted keys, numpy arrays as lists, NaN and infinity refused).
"""

from __future__ import annotations

import json
import os
import sqlite3
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from enum import Enum
from pathlib import Path
from typing import Any, Literal, Self

import numpy as np

from cellctl.folders import folder_problem
from cellctl.store.records import SchemaTooNew, StoreError
from cellctl.store.schema import MIGRATIONS, schema_version
from cellctl.store.upgrade import StoreUpgrade, copies_for_rollback, migrate_keeping_a_copy

Synchronous = Literal["FULL", "NORMAL"]


def utcnow() -> datetime:
    """The default clock: now, UTC."""
    return datetime.now(timezone.utc)


def ts(t: datetime) -> str:
    """A timezone-aware datetime as stored: ISO 8601 in UTC, with microseconds."""
    if t.tzinfo is None:
        raise ValueError("timestamps must be timezone-aware (UTC)")
    return t.astimezone(timezone.utc).isoformat(timespec="microseconds")


def dt(s: str | None) -> datetime | None:
    """A stored timestamp back (None stays None)."""
    return None if s is None else datetime.fromisoformat(s)


def need(name: str, value: str) -> None:
    """Refuse an empty or blank text field, naming it."""
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{name} must be a non-empty string")


def _json_default(obj: object) -> object:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Enum):
        return obj.value
    if isinstance(obj, datetime):
        return ts(obj)
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)  # type: ignore[type-var]
    raise TypeError(f"cannot store a {type(obj).__name__} as JSON")


def to_json(what: str, obj: object) -> str:
    """Canonical JSON (sorted keys); NaN and infinity are refused naming ``what``."""
    try:
        return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False, default=_json_default)
    except ValueError as err:
        raise ValueError(f"{what} contains NaN or infinity, which is never a valid figure: {err}") from None
    except TypeError as err:
        raise ValueError(f"{what} cannot be stored as JSON: {err}") from None


def from_json(s: str | None) -> Any:
    """Stored JSON back (None stays None)."""
    return None if s is None else json.loads(s)


class StorePathError(StoreError, OSError):
    """``[store] path`` cannot hold the database file; the message names the setting and the fix."""


class StoreDamaged(StorePathError):
    """The file at ``[store] path`` is not a SQLite database, or a damaged one; the message names the file and the fix."""


STORE_PATH_FIX = "change [store] path to a file in a folder the service can write (e.g. path = \"var/cellctl.db\")"


def check_store_path(path: Path, *, creatable: bool = False) -> None:
    """Raise :class:`StorePathError` unless ``path`` can be the database file: not a folder, in an existing folder
    this process may write in (``creatable``: or in one :func:`make_store_folder` could create, the dry run of
    ``config check --secrets``), the file itself, if there, readable and writable."""
    if path.is_dir():
        raise StorePathError(f"[store] path {path} is a folder; the store is one SQLite file: give a file's path, "
                             f"e.g. path = \"{path / 'cellctl.db'}\"")
    for folder in path.parents:
        if folder.exists() and not folder.is_dir():
            raise StorePathError(f"[store] path {path} lies under {folder}, which is a file, not a folder; {STORE_PATH_FIX}")
    if path.parent.is_dir():
        # SQLite writes the file, its -wal and -shm beside it, and the service its .lock: the folder must allow it.
        if not os.access(path.parent, os.W_OK | os.X_OK):
            raise StorePathError(f"[store] path {path}: the service's user may not write in {path.parent}; give it "
                                 f"the right to, or {STORE_PATH_FIX}")  # fmt: skip
        if path.is_file() and not os.access(path, os.R_OK | os.W_OK):
            raise StorePathError(f"[store] path {path}: the service's user may not read and write the file; give it "
                                 f"the right to, or {STORE_PATH_FIX}")  # fmt: skip
        return
    if not creatable:
        raise StorePathError(f"[store] path {path}: its folder {path.parent} does not exist: create it or {STORE_PATH_FIX}")
    if (why := folder_problem(path.parent)) is not None:
        raise StorePathError(f"[store] path {path}: its folder cannot be created ({why}); {STORE_PATH_FIX}")


def make_store_folder(path: Path) -> None:
    """Create the folder of the database file ``path`` (and its parents); :class:`StorePathError` if it cannot be."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        check_store_path(path, creatable=True)  # a file in the way, or the folder without the right, is named
        why = err.strerror or err
        raise StorePathError(f"[store] path {path}: its folder cannot be created ({why}); {STORE_PATH_FIX}") from None


@dataclass(frozen=True)
class StoreInfo:
    """What :meth:`Database.info` reports: the file, its schema version, journal mode and sync level."""

    path: Path
    schema_version: int
    journal_mode: str
    synchronous: str


_DAMAGED_FIX = (
    "restore it from a backup, or move it aside to start an empty store (`sqlite3 OLD .recover | sqlite3 NEW` "
    "saves what is still readable)"
)


def check_intact(conn: sqlite3.Connection, path: Path) -> None:
    """Refuse a damaged database file (``PRAGMA quick_check``: every page and row read once, no index cross-check)."""
    rows = conn.execute("PRAGMA quick_check(3)").fetchall()  # up to 3 faults, each on one line
    found = [" ".join(str(r[0]).replace("*** in database main ***", "").split()) for r in rows]
    if found != ["ok"]:
        raise StoreDamaged(f"[store] path {path} is damaged (quick_check: {'; '.join(found)}): {_DAMAGED_FIX}")


def _naming_the_file(err: BaseException, path: Path) -> StoreError | None:
    """A newer schema, or a file that is not (intact) SQLite, said with the file and the fix; None for other faults."""
    if isinstance(err, SchemaTooNew):
        kept = copies_for_rollback(path, len(MIGRATIONS))
        where = f"; the copy kept when it was upgraded from this release's schema is {kept[-1]}" if kept else ""
        return SchemaTooNew(f"[store] path {path}: {err}{where} (README, Backup, upgrade and rollback)")
    if isinstance(err, sqlite3.DatabaseError) and not isinstance(err, sqlite3.OperationalError):
        return StoreDamaged(f"[store] path {path} is not a SQLite database, or a damaged one ({err}): {_DAMAGED_FIX}")
    return None


class Database:
    """One open database: its connection, its path and the clock that stamps its rows.

    Open with :meth:`open`; close with :meth:`close` (or use as a context manager).
    """

    def __init__(self, conn: sqlite3.Connection, path: Path, clock: Callable[[], datetime]) -> None:
        self._conn = conn
        self._path = path
        self._clock = clock
        self.upgrade: StoreUpgrade | None = None
        """The migration :meth:`open` did on a store of an earlier release (with the copy it kept), else None."""

    @classmethod
    def open(
        cls,
        path: str | Path,
        *,
        synchronous: Synchronous = "FULL",
        busy_timeout_s: float = 5.0,
        clock: Callable[[], datetime] = utcnow,
    ) -> Self:
        """Open (creating if needed) the database at ``path``, switch it to WAL, check it is intact and migrate it.

        ``busy_timeout_s`` (seconds) is how long a write waits for another connection's lock. A file that is not
        SQLite or is damaged raises :class:`StoreDamaged`, a newer schema :class:`SchemaTooNew`, both naming the file.
        A store of an earlier release is copied before it is migrated (:mod:`cellctl.store.upgrade`).
        """
        p = Path(path)
        if str(path) == ":memory:" or not str(path):
            raise ValueError("the store needs a file path (WAL mode and crash recovery need a file), not ':memory:'")
        if synchronous not in ("FULL", "NORMAL"):
            raise ValueError(f"synchronous must be 'FULL' or 'NORMAL', got {synchronous!r}")
        check_store_path(p)
        try:
            conn = sqlite3.connect(p, isolation_level=None, timeout=busy_timeout_s)
        except sqlite3.OperationalError as err:  # e.g. a folder the service may not write in
            raise StorePathError(f"[store] path {p}: SQLite cannot open it ({err}); {STORE_PATH_FIX}") from None
        try:
            mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise StoreError(f"{p}: SQLite refused WAL mode (journal_mode is {mode}); use a local file system")
            conn.execute(f"PRAGMA synchronous = {synchronous}")
            conn.execute("PRAGMA foreign_keys = ON")
            conn.execute(f"PRAGMA busy_timeout = {int(busy_timeout_s * 1000)}")
            check_intact(conn, p)
            upgrade = migrate_keeping_a_copy(conn, p, clock())
        except BaseException as err:
            conn.close()
            if (named := _naming_the_file(err, p)) is not None:
                raise named from None
            raise
        db = cls(conn, p, clock)
        db.upgrade = upgrade
        return db

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def info(self) -> StoreInfo:
        """Where the database is, its schema version, journal mode and sync level."""
        sync = {0: "OFF", 1: "NORMAL", 2: "FULL", 3: "EXTRA"}[self._conn.execute("PRAGMA synchronous").fetchone()[0]]
        return StoreInfo(
            self._path,
            schema_version(self._conn),
            self._conn.execute("PRAGMA journal_mode").fetchone()[0],
            sync,
        )

    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        """One write transaction, taken at once (no lock upgrade deadlocks), committed on exit."""
        self._conn.execute("BEGIN IMMEDIATE")
        try:
            yield self._conn
        except BaseException:
            self._conn.execute("ROLLBACK")
            raise
        self._conn.execute("COMMIT")
