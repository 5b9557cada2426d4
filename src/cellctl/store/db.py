"""The cell's SQLite store (WAL mode): cycles, alarms, audit log, idempotency keys, calibrations.

This class is synchronous and owns one connection; it must be used from the thread that opened
it (sqlite3's default check). The service uses it through :class:`cellctl.store.aio.AsyncCellStore`,
which runs every call on one dedicated thread.

Durability: every method that changes something commits before it returns (``synchronous=FULL``
by default, so a commit also survives a power cut). In particular :meth:`begin_step` for the
install step writes the install-started marker and commits *before* the caller commands the
robot; a cycle with that marker never gets its install step again, whatever happens.
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from enum import Enum
from pathlib import Path
from typing import Any, Literal

import numpy as np

from cellctl.cell.alarms import Alarm, AlarmCode, FaultClass, Severity
from cellctl.cell.packml import EventKind, MachineEvent
from cellctl.cell.tags import CycleStep, PackMLCommand
from cellctl.store.records import (
    AuditChainBroken,
    AuditEntry,
    CalibrationVersion,
    CycleRecord,
    CycleRequest,
    CycleState,
    CycleStateError,
    IdempotencyConflict,
    IdempotencyInFlight,
    ImageRef,
    InstallAlreadyStarted,
    InterruptedCycle,
    RecoveryReport,
    StepRecord,
    StoredResponse,
    StoreError,
    SubmitResult,
    UnknownCycle,
)
from cellctl.store.jobs import JobRows
from cellctl.store.retention import RetentionRows
from cellctl.store.schema import migrate, schema_version

GENESIS_HASH = "0" * 64
Synchronous = Literal["FULL", "NORMAL"]


def _utcnow() -> datetime:
    return datetime.now(timezone.utc)


def _ts(t: datetime) -> str:
    if t.tzinfo is None:
        raise ValueError("timestamps must be timezone-aware (UTC)")
    return t.astimezone(timezone.utc).isoformat(timespec="microseconds")


def _dt(s: str | None) -> datetime | None:
    return None if s is None else datetime.fromisoformat(s)


def _json_default(obj: object) -> object:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Enum):
        return obj.value
    if isinstance(obj, datetime):
        return _ts(obj)
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


def _from_json(s: str | None) -> Any:
    return None if s is None else json.loads(s)


def _hash_request(identity: Mapping[str, Any]) -> str:
    return hashlib.sha256(to_json("request", identity).encode()).hexdigest()


@dataclass(frozen=True)
class StoreInfo:
    path: Path
    schema_version: int
    journal_mode: str
    synchronous: str


class CellStore(JobRows, RetentionRows):
    """Open with :meth:`open`; close with :meth:`close` (or use as a context manager)."""

    _to_json = staticmethod(lambda what, obj: to_json(what, obj))

    def __init__(self, conn: sqlite3.Connection, path: Path, clock: Callable[[], datetime]) -> None:
        self._conn = conn
        self._path = path
        self._clock = clock

    # -- lifecycle ----------------------------------------------------------------------------

    @classmethod
    def open(
        cls,
        path: str | Path,
        *,
        synchronous: Synchronous = "FULL",
        busy_timeout_s: float = 5.0,
        clock: Callable[[], datetime] = _utcnow,
    ) -> CellStore:
        """Open (creating if needed) the database at ``path``, switch it to WAL and migrate it."""
        p = Path(path)
        if str(path) == ":memory:" or not str(path):
            raise ValueError("the store needs a file path (WAL mode and crash recovery need a file), not ':memory:'")
        if synchronous not in ("FULL", "NORMAL"):
            raise ValueError(f"synchronous must be 'FULL' or 'NORMAL', got {synchronous!r}")
        if not p.parent.is_dir():
            raise StoreError(f"store directory {p.parent} does not exist: create it or change [store] path")
        conn = sqlite3.connect(p, isolation_level=None, timeout=busy_timeout_s)
        try:
            mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise StoreError(f"{p}: SQLite refused WAL mode (journal_mode is {mode}); use a local file system")
            conn.execute(f"PRAGMA synchronous = {synchronous}")
            conn.execute("PRAGMA foreign_keys = ON")
            conn.execute(f"PRAGMA busy_timeout = {int(busy_timeout_s * 1000)}")
            migrate(conn)
        except BaseException:
            conn.close()
            raise
        return cls(conn, p, clock)

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> CellStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def info(self) -> StoreInfo:
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

    # -- recovery -----------------------------------------------------------------------------

    def recover(self) -> RecoveryReport:
        """Run once at startup, before anything else writes.

        Every cycle left queued or running by a process that died becomes ``interrupted`` with
        the step it was in; steps left open get an error; alarms left active are closed (the
        watchdog re-raises what is still wrong); in-flight idempotency keys of non-cycle requests
        are released (their effect is unknown; the cell restarts in Aborted anyway).
        Calling it again finds nothing.
        """
        now = _ts(self._clock())
        with self._tx() as c:
            rows = c.execute(
                "SELECT id, state, current_step, install_started_at FROM cycles "
                "WHERE state IN ('queued', 'running') ORDER BY id"
            ).fetchall()
            found = tuple(
                InterruptedCycle(int(r[0]), CycleState(r[1]), CycleStep(r[2]), r[3] is not None) for r in rows
            )
            c.execute(
                "UPDATE cycles SET state = 'interrupted', interrupted_step = current_step, interrupted_at = ? "
                "WHERE state IN ('queued', 'running')",
                (now,),
            )
            c.execute(
                "UPDATE cycle_steps SET error = 'interrupted: the cell process stopped during this step' "
                "WHERE finished_at IS NULL AND error IS NULL AND cycle_id IN "
                f"({','.join(str(i.cycle_id) for i in found) or 'NULL'})"
            )
            alarms = c.execute("UPDATE alarms SET active = 0, cleared_at = ? WHERE active = 1", (now,)).rowcount
            keys = c.execute(
                "DELETE FROM idempotency_keys WHERE response_json IS NULL AND cycle_id IS NULL"
            ).rowcount
        return RecoveryReport(found, alarms, keys)

    # -- cycles -------------------------------------------------------------------------------

    def submit_cycle(self, request: CycleRequest, *, scope: str, key: str, actor: str) -> SubmitResult:
        """Queue a cycle under an idempotency key.

        Same key (in the same scope) and same request: the cycle made the first time
        (``created`` False). Same key, different request: :class:`IdempotencyConflict`.
        """
        _need("scope", scope)
        _need("idempotency key", key)
        _need("actor", actor)
        identity = request.identity()
        digest = _hash_request(identity)
        now = _ts(self._clock())
        with self._tx() as c:
            row = c.execute(
                "SELECT request_hash, request_json, cycle_id FROM idempotency_keys WHERE scope = ? AND key = ?",
                (scope, key),
            ).fetchone()
            if row is not None:
                if row[0] != digest or row[2] is None:
                    old = json.loads(row[1])
                    diff = {f: (old.get(f), v) for f, v in identity.items() if old.get(f) != v}
                    raise IdempotencyConflict(scope, key, diff or {"request kind": ("other", "cycle")})
                cycle_id = int(row[2])
                created = False
            else:
                cur = c.execute(
                    "INSERT INTO cycles (idempotency_scope, idempotency_key, recipe, part_id, car_id, source, actor, "
                    "state, created_at) VALUES (?, ?, ?, ?, ?, ?, ?, 'queued', ?)",
                    (scope, key, request.recipe, request.part_id, request.car_id, request.source, actor, now),
                )
                cycle_id = int(cur.lastrowid)  # type: ignore[arg-type]
                c.execute(
                    "INSERT INTO idempotency_keys (scope, key, request_hash, request_json, cycle_id, created_at) "
                    "VALUES (?, ?, ?, ?, ?, ?)",
                    (scope, key, digest, to_json("request", identity), cycle_id, now),
                )
                created = True
        return SubmitResult(self.cycle(cycle_id), created)

    def cycle_for_key(self, scope: str, key: str) -> CycleRecord | None:
        """The cycle an idempotency key made, or None if the key is unknown (or not a cycle's)."""
        row = self._conn.execute(
            "SELECT cycle_id FROM idempotency_keys WHERE scope = ? AND key = ?", (scope, key)
        ).fetchone()
        return None if row is None or row[0] is None else self.cycle(int(row[0]))

    def start_cycle(self, cycle_id: int) -> CycleRecord:
        """queued -> running."""
        self._transition(cycle_id, "queued", "state = 'running', started_at = ?", (_ts(self._clock()),), "start")
        return self.cycle(cycle_id)

    def begin_step(self, cycle_id: int, step: CycleStep) -> StepRecord:
        """Record that ``step`` starts now (a new attempt if it ran before in this cycle).

        For :attr:`CycleStep.INSTALL` this is the install-started marker: it is committed before
        this returns, so call it *before* commanding the robot, and do not command the robot if it
        raises. It raises :class:`InstallAlreadyStarted` if this cycle's install ever started.
        """
        step = CycleStep(step)
        if step == CycleStep.NONE:
            raise ValueError("step must be a real cycle step, not NONE")
        now = self._clock()
        with self._tx() as c:
            state, install_started = self._cycle_state(c, cycle_id)
            if state != CycleState.RUNNING:
                raise CycleStateError(cycle_id, f"is {state.value}, a step can only begin in a running cycle")
            if step == CycleStep.INSTALL:
                if install_started is not None:
                    raise InstallAlreadyStarted(cycle_id, install_started)
                c.execute("UPDATE cycles SET install_started_at = ? WHERE id = ?", (_ts(now), cycle_id))
            attempt = 1 + c.execute(
                "SELECT COUNT(*) FROM cycle_steps WHERE cycle_id = ? AND step = ?", (cycle_id, int(step))
            ).fetchone()[0]
            c.execute("UPDATE cycles SET current_step = ? WHERE id = ?", (int(step), cycle_id))
            c.execute(
                "INSERT INTO cycle_steps (cycle_id, step, attempt, started_at) VALUES (?, ?, ?, ?)",
                (cycle_id, int(step), attempt, _ts(now)),
            )
        return StepRecord(step, attempt, now, None, None, None, {}, None)

    def finish_step(
        self,
        cycle_id: int,
        step: CycleStep,
        *,
        ok: bool,
        figures: Mapping[str, Any],
        error: str | None = None,
    ) -> StepRecord:
        """Close the latest attempt of ``step`` with its figures (any JSON-able mapping; numpy ok)."""
        step = CycleStep(step)
        fig_json = to_json(f"figures of step {step.name.lower()}", dict(figures))
        now = self._clock()
        with self._tx() as c:
            row = c.execute(
                "SELECT id, attempt, started_at, finished_at FROM cycle_steps WHERE cycle_id = ? AND step = ? "
                "ORDER BY attempt DESC LIMIT 1",
                (cycle_id, int(step)),
            ).fetchone()
            if row is None:
                self._cycle_state(c, cycle_id)
                raise CycleStateError(cycle_id, f"step {step.name.lower()} was never begun")
            if row[3] is not None:
                raise CycleStateError(cycle_id, f"step {step.name.lower()} attempt {row[1]} is already finished")
            started = datetime.fromisoformat(row[2])
            duration = (now - started).total_seconds()
            c.execute(
                "UPDATE cycle_steps SET finished_at = ?, duration_s = ?, ok = ?, figures_json = ?, error = ? "
                "WHERE id = ?",
                (_ts(now), duration, int(bool(ok)), fig_json, error, row[0]),
            )
        return StepRecord(step, int(row[1]), started, now, duration, bool(ok), json.loads(fig_json), error)

    def add_image(self, cycle_id: int, step: CycleStep, *, name: str, uri: str) -> ImageRef:
        """Reference an image saved elsewhere (the store keeps the reference, not the pixels)."""
        _need("image name", name)
        _need("image uri", uri)
        now = self._clock()
        with self._tx() as c:
            self._cycle_state(c, cycle_id)
            c.execute(
                "INSERT INTO cycle_images (cycle_id, step, name, uri, created_at) VALUES (?, ?, ?, ?, ?)",
                (cycle_id, int(CycleStep(step)), name, uri, _ts(now)),
            )
        return ImageRef(CycleStep(step), name, uri, now)

    def complete_cycle(
        self, cycle_id: int, *, result: Mapping[str, Any], true_error: Mapping[str, Any] | None = None
    ) -> CycleRecord:
        """running -> done, with the result (and, in simulation, the true error)."""
        self._transition(
            cycle_id,
            "running",
            "state = 'done', finished_at = ?, current_step = 0, result_json = ?, true_error_json = ?",
            (_ts(self._clock()), to_json("result", dict(result)), _opt_json("true_error", true_error)),
            "complete",
        )
        return self.cycle(cycle_id)

    def fail_cycle(
        self,
        cycle_id: int,
        *,
        error: str,
        result: Mapping[str, Any] | None = None,
        true_error: Mapping[str, Any] | None = None,
    ) -> CycleRecord:
        """queued or running -> failed, saying why."""
        _need("error", error)
        self._transition(
            cycle_id,
            ("queued", "running"),
            "state = 'failed', finished_at = ?, error = ?, result_json = ?, true_error_json = ?",
            (_ts(self._clock()), error, _opt_json("result", result), _opt_json("true_error", true_error)),
            "fail",
        )
        return self.cycle(cycle_id)

    def resume_cycle(self, cycle_id: int) -> CycleRecord:
        """interrupted -> running, only if its install never started (else InstallAlreadyStarted).

        The interrupted step stays recorded; the orchestrator decides where to pick up (typically
        re-measuring from align, since the car or the robot may have moved).
        """
        with self._tx() as c:
            state, install_started = self._cycle_state(c, cycle_id)
            if state != CycleState.INTERRUPTED:
                raise CycleStateError(cycle_id, f"is {state.value}; only an interrupted cycle can be resumed")
            if install_started is not None:
                raise InstallAlreadyStarted(cycle_id, install_started)
            c.execute("UPDATE cycles SET state = 'running', current_step = 0 WHERE id = ?", (cycle_id,))
        return self.cycle(cycle_id)

    def cycle(self, cycle_id: int) -> CycleRecord:
        row = self._conn.execute(f"SELECT {_CYCLE_COLUMNS} FROM cycles WHERE id = ?", (cycle_id,)).fetchone()
        if row is None:
            raise UnknownCycle(cycle_id)
        steps = tuple(
            StepRecord(CycleStep(r[0]), r[1], datetime.fromisoformat(r[2]), _dt(r[3]), r[4],
                       None if r[5] is None else bool(r[5]), json.loads(r[6]), r[7])  # fmt: skip
            for r in self._conn.execute(
                "SELECT step, attempt, started_at, finished_at, duration_s, ok, figures_json, error "
                "FROM cycle_steps WHERE cycle_id = ? ORDER BY id",
                (cycle_id,),
            )
        )
        images = tuple(
            ImageRef(CycleStep(r[0]), r[1], r[2], datetime.fromisoformat(r[3]), _dt(r[4]), r[5])
            for r in self._conn.execute(
                "SELECT step, name, uri, created_at, pruned_at, pruned_reason FROM cycle_images "
                "WHERE cycle_id = ? ORDER BY id",
                (cycle_id,),
            )
        )
        return _cycle_from_row(row, steps, images)

    def cycles(
        self, *, limit: int = 50, before_id: int | None = None, state: CycleState | None = None
    ) -> list[CycleRecord]:
        """Newest first, without steps and images (fetch one with :meth:`cycle` for those)."""
        if not (1 <= limit <= 1000):
            raise ValueError(f"limit must be in 1..1000, got {limit}")
        where, args = [], []
        if before_id is not None:
            where.append("id < ?")
            args.append(before_id)
        if state is not None:
            where.append("state = ?")
            args.append(CycleState(state).value)
        sql = f"SELECT {_CYCLE_COLUMNS} FROM cycles"
        if where:
            sql += " WHERE " + " AND ".join(where)
        sql += " ORDER BY id DESC LIMIT ?"
        return [_cycle_from_row(r, (), ()) for r in self._conn.execute(sql, (*args, limit))]

    def cycle_counts(self) -> dict[CycleState, int]:
        counts = {s: 0 for s in CycleState}
        for state, n in self._conn.execute("SELECT state, COUNT(*) FROM cycles GROUP BY state"):
            counts[CycleState(state)] = int(n)
        return counts

    # -- idempotency of other requests (commands) ---------------------------------------------

    def claim_key(self, scope: str, key: str, request: Mapping[str, Any]) -> StoredResponse | None:
        """Start an idempotent request. None: first time, go ahead and :meth:`complete_key` after.
        A StoredResponse: replay it. Raises IdempotencyInFlight (the first is still running) or
        IdempotencyConflict (same key, different request)."""
        _need("scope", scope)
        _need("idempotency key", key)
        req_json = to_json("request", dict(request))
        digest = hashlib.sha256(req_json.encode()).hexdigest()
        with self._tx() as c:
            row = c.execute(
                "SELECT request_hash, request_json, cycle_id, response_json, completed_at FROM idempotency_keys "
                "WHERE scope = ? AND key = ?",
                (scope, key),
            ).fetchone()
            if row is None:
                c.execute(
                    "INSERT INTO idempotency_keys (scope, key, request_hash, request_json, created_at) "
                    "VALUES (?, ?, ?, ?, ?)",
                    (scope, key, digest, req_json, _ts(self._clock())),
                )
                return None
        if row[0] != digest or row[2] is not None:
            old = json.loads(row[1])
            new = dict(request)
            diff = {f: (old.get(f), new.get(f)) for f in sorted(set(old) | set(new)) if old.get(f) != new.get(f)}
            raise IdempotencyConflict(scope, key, diff or {"request kind": ("cycle", "other")})
        if row[3] is None:
            raise IdempotencyInFlight(scope, key)
        return StoredResponse(scope, key, json.loads(row[3]), datetime.fromisoformat(row[4]))

    def complete_key(self, scope: str, key: str, response: Mapping[str, Any]) -> None:
        with self._tx() as c:
            n = c.execute(
                "UPDATE idempotency_keys SET response_json = ?, completed_at = ? "
                "WHERE scope = ? AND key = ? AND response_json IS NULL AND cycle_id IS NULL",
                (to_json("response", dict(response)), _ts(self._clock()), scope, key),
            ).rowcount
        if n != 1:
            raise StoreError(f"idempotency key {key!r} ({scope}) is not an open claim: call claim_key first")

    def release_key(self, scope: str, key: str) -> None:
        """Drop an open claim whose request did nothing (so a retry runs it)."""
        with self._tx() as c:
            c.execute(
                "DELETE FROM idempotency_keys WHERE scope = ? AND key = ? AND response_json IS NULL "
                "AND cycle_id IS NULL",
                (scope, key),
            )

    def forget_keys(self, scope: str, *, created_before: datetime) -> int:
        """Drop finished keys of ``scope`` older than ``created_before`` (e.g. a PLC counter that
        wraps); cycles keep their key as history. Returns how many were dropped."""
        with self._tx() as c:
            return c.execute(
                "DELETE FROM idempotency_keys WHERE scope = ? AND created_at < ? "
                "AND (response_json IS NOT NULL OR cycle_id IS NOT NULL)",
                (scope, _ts(created_before)),
            ).rowcount

    # -- alarms -------------------------------------------------------------------------------

    def save_alarm(self, alarm: Alarm) -> None:
        """Insert or update an alarm record (call it on every alarm event)."""
        with self._tx() as c:
            c.execute(
                "INSERT INTO alarms (uid, code, value, message, category, severity, source, raised_at, active, "
                "condition, ack_at, ack_by, cleared_at, reaction, cycle_id) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) "
                "ON CONFLICT (uid) DO UPDATE SET active = excluded.active, ack_at = excluded.ack_at, "
                "ack_by = excluded.ack_by, cleared_at = excluded.cleared_at, reaction = excluded.reaction",
                (
                    alarm.uid, int(alarm.code), alarm.value, alarm.message, int(alarm.category),
                    int(alarm.severity), alarm.source, _ts(alarm.raised_at), int(alarm.active),
                    int(alarm.condition), None if alarm.ack_at is None else _ts(alarm.ack_at), alarm.ack_by,
                    None if alarm.cleared_at is None else _ts(alarm.cleared_at),
                    None if alarm.reaction is None else int(alarm.reaction), alarm.cycle_id,
                ),
            )  # fmt: skip

    def alarms(self, *, active_only: bool = False, limit: int = 100) -> list[Alarm]:
        """Newest first."""
        sql = f"SELECT {_ALARM_COLUMNS} FROM alarms"
        if active_only:
            sql += " WHERE active = 1"
        sql += " ORDER BY raised_at DESC LIMIT ?"
        return [_alarm_from_row(r) for r in self._conn.execute(sql, (limit,))]

    # -- audit log ----------------------------------------------------------------------------

    def append_audit(
        self,
        *,
        actor: str,
        source: str,
        action: str,
        params: Mapping[str, Any] | None = None,
        state_before: str | None = None,
        state_after: str | None = None,
        result: str = "ok",
        cycle_id: int | None = None,
        at: datetime | None = None,
    ) -> AuditEntry:
        """Append one entry; each carries the hash of the previous one (tamper evidence)."""
        _need("actor", actor)
        _need("source", source)
        _need("action", action)
        params_json = to_json("audit params", dict(params or {}))
        when = _ts(at or self._clock())
        with self._tx() as c:
            last = c.execute("SELECT seq, hash FROM audit_log ORDER BY seq DESC LIMIT 1").fetchone()
            seq, prev = (1, GENESIS_HASH) if last is None else (int(last[0]) + 1, str(last[1]))
            fields = (seq, when, actor, source, action, params_json, state_before, state_after, result, cycle_id)
            digest = _audit_hash(prev, fields)
            c.execute(
                "INSERT INTO audit_log (seq, at, actor, source, action, params_json, state_before, state_after, "
                "result, cycle_id, prev_hash, hash) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (*fields, prev, digest),
            )
        return AuditEntry(seq, datetime.fromisoformat(when), actor, source, action, json.loads(params_json),
                          state_before, state_after, result, cycle_id, prev, digest)  # fmt: skip

    def append_machine_event(self, event: MachineEvent, *, cycle_id: int | None = None) -> AuditEntry:
        """The audit entry of a PackML machine event (command, SC, mode change or cycle step)."""
        if event.kind == EventKind.COMMAND:
            assert event.command is not None
            action = f"command:{event.command.name.lower()}"
        else:
            action = event.kind.value
        params: dict[str, Any] = {"event_seq": event.seq}
        if event.kind == EventKind.MODE:
            params.update(mode_before=event.mode_before.name, mode_after=event.mode_after.name)
        if event.step_before != event.step_after:
            params.update(step_before=event.step_before.name, step_after=event.step_after.name)
        return self.append_audit(
            actor=event.actor,
            source=event.source,
            action=action,
            params=params,
            state_before=event.state_before.name,
            state_after=event.state_after.name,
            cycle_id=cycle_id,
            at=event.at,
        )

    def audit_entries(self, *, after_seq: int = 0, limit: int = 100) -> list[AuditEntry]:
        """Oldest first, from ``after_seq`` on."""
        return [
            AuditEntry(r[0], datetime.fromisoformat(r[1]), r[2], r[3], r[4], json.loads(r[5]), r[6], r[7], r[8],
                       r[9], r[10], r[11])  # fmt: skip
            for r in self._conn.execute(
                "SELECT seq, at, actor, source, action, params_json, state_before, state_after, result, cycle_id, "
                "prev_hash, hash FROM audit_log WHERE seq > ? ORDER BY seq LIMIT ?",
                (after_seq, limit),
            )
        ]

    def verify_audit_chain(self) -> int:
        """Recompute the hash chain; returns the number of entries, raises AuditChainBroken."""
        prev = GENESIS_HASH
        expected_seq = 1
        for r in self._conn.execute(
            "SELECT seq, at, actor, source, action, params_json, state_before, state_after, result, cycle_id, "
            "prev_hash, hash FROM audit_log ORDER BY seq"
        ):
            seq = int(r[0])
            if seq != expected_seq:
                raise AuditChainBroken(seq, f"expected entry {expected_seq} here: entries are missing")
            if r[10] != prev:
                raise AuditChainBroken(seq, "does not link to the previous entry")
            if _audit_hash(prev, tuple(r[:10])) != r[11]:
                raise AuditChainBroken(seq, "its content does not match its hash")
            prev = r[11]
            expected_seq += 1
        return expected_seq - 1

    # -- calibration history ------------------------------------------------------------------

    def save_calibration(
        self, kind: str, data: Mapping[str, Any], *, metadata: Mapping[str, Any], created_by: str
    ) -> CalibrationVersion:
        """Store a new version of calibration ``kind`` (versions count 1, 2, ... per kind)."""
        _need("calibration kind", kind)
        _need("created_by", created_by)
        data_json = to_json(f"calibration {kind}", dict(data))
        meta_json = to_json(f"calibration {kind} metadata", dict(metadata))
        now = self._clock()
        with self._tx() as c:
            version = 1 + c.execute(
                "SELECT COALESCE(MAX(version), 0) FROM calibrations WHERE kind = ?", (kind,)
            ).fetchone()[0]
            c.execute(
                "INSERT INTO calibrations (kind, version, data_json, metadata_json, created_at, created_by) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                (kind, version, data_json, meta_json, _ts(now), created_by),
            )
        return CalibrationVersion(kind, version, json.loads(data_json), json.loads(meta_json), now, created_by)

    def calibration(self, kind: str, version: int | None = None) -> CalibrationVersion | None:
        """A version of ``kind`` (the latest if ``version`` is None), or None if there is none."""
        sql = "SELECT kind, version, data_json, metadata_json, created_at, created_by FROM calibrations WHERE kind = ?"
        args: tuple[Any, ...] = (kind,)
        if version is None:
            sql += " ORDER BY version DESC LIMIT 1"
        else:
            sql += " AND version = ?"
            args = (kind, version)
        r = self._conn.execute(sql, args).fetchone()
        return None if r is None else _calibration_from_row(r)

    def calibration_history(self, kind: str) -> list[CalibrationVersion]:
        """All versions of ``kind``, oldest first."""
        return [
            _calibration_from_row(r)
            for r in self._conn.execute(
                "SELECT kind, version, data_json, metadata_json, created_at, created_by FROM calibrations "
                "WHERE kind = ? ORDER BY version",
                (kind,),
            )
        ]

    def calibration_kinds(self) -> list[str]:
        return [r[0] for r in self._conn.execute("SELECT DISTINCT kind FROM calibrations ORDER BY kind")]

    # -- internals ----------------------------------------------------------------------------

    def _cycle_state(self, c: sqlite3.Connection, cycle_id: int) -> tuple[CycleState, datetime | None]:
        row = c.execute("SELECT state, install_started_at FROM cycles WHERE id = ?", (cycle_id,)).fetchone()
        if row is None:
            raise UnknownCycle(cycle_id)
        return CycleState(row[0]), _dt(row[1])

    def _transition(
        self, cycle_id: int, from_states: str | tuple[str, ...], set_sql: str, args: tuple[Any, ...], verb: str
    ) -> None:
        allowed = (from_states,) if isinstance(from_states, str) else from_states
        with self._tx() as c:
            state, _ = self._cycle_state(c, cycle_id)
            if state.value not in allowed:
                raise CycleStateError(
                    cycle_id, f"is {state.value}; it can {verb} only when {' or '.join(allowed)}"
                )
            c.execute(f"UPDATE cycles SET {set_sql} WHERE id = ?", (*args, cycle_id))


def _need(name: str, value: str) -> None:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{name} must be a non-empty string")


def _opt_json(what: str, obj: Mapping[str, Any] | None) -> str | None:
    return None if obj is None else to_json(what, dict(obj))


def _audit_hash(prev: str, fields: tuple[Any, ...]) -> str:
    payload = json.dumps([prev, *fields], separators=(",", ":"), ensure_ascii=False)
    return hashlib.sha256(payload.encode()).hexdigest()


_CYCLE_COLUMNS = (
    "id, idempotency_scope, idempotency_key, recipe, part_id, car_id, source, actor, state, current_step, "
    "result_json, error, true_error_json, created_at, started_at, finished_at, install_started_at, "
    "interrupted_step, interrupted_at"
)


def _cycle_from_row(r: tuple[Any, ...], steps: tuple[StepRecord, ...], images: tuple[ImageRef, ...]) -> CycleRecord:
    return CycleRecord(
        id=int(r[0]),
        idempotency_scope=r[1],
        idempotency_key=r[2],
        request=CycleRequest(recipe=r[3], part_id=r[4], car_id=r[5], source=r[6]),
        actor=r[7],
        state=CycleState(r[8]),
        current_step=CycleStep(r[9]),
        result=_from_json(r[10]),
        error=r[11],
        true_error=_from_json(r[12]),
        created_at=datetime.fromisoformat(r[13]),
        started_at=_dt(r[14]),
        finished_at=_dt(r[15]),
        install_started_at=_dt(r[16]),
        interrupted_step=None if r[17] is None else CycleStep(r[17]),
        interrupted_at=_dt(r[18]),
        steps=steps,
        images=images,
    )


_ALARM_COLUMNS = (
    "uid, code, value, message, category, severity, source, raised_at, active, condition, ack_at, ack_by, "
    "cleared_at, reaction, cycle_id"
)


def _alarm_from_row(r: tuple[Any, ...]) -> Alarm:
    return Alarm(
        uid=r[0],
        code=AlarmCode(r[1]),
        value=int(r[2]),
        message=r[3],
        category=FaultClass(r[4]),
        severity=Severity(r[5]),
        source=r[6],
        raised_at=datetime.fromisoformat(r[7]),
        active=bool(r[8]),
        condition=bool(r[9]),
        ack_at=_dt(r[10]),
        ack_by=r[11],
        cleared_at=_dt(r[12]),
        reaction=None if r[13] is None else PackMLCommand(r[13]),
        cycle_id=r[14],
    )


def _calibration_from_row(r: tuple[Any, ...]) -> CalibrationVersion:
    return CalibrationVersion(r[0], int(r[1]), json.loads(r[2]), json.loads(r[3]), datetime.fromisoformat(r[4]), r[5])


__all__ = ["CellStore", "StoreInfo", "to_json", "GENESIS_HASH"]
