"""Cycles in the store: a cycle with its steps and image references, and the idempotency keys.

A cycle is queued under an idempotency key (:meth:`CycleRows.submit_cycle`), runs its steps
(each attempt a row of ``cycle_steps`` with its figures), references its images (the files live
elsewhere) and ends done, failed or interrupted. Requests that are not cycles (PackML commands
over REST, say) use the same keys table through :meth:`CycleRows.claim_key`.

The install-started marker: :meth:`CycleRows.begin_step` for :attr:`CycleStep.INSTALL` writes it
and commits *before* the caller commands the robot; a cycle with that marker never gets its install
step again, whatever happens (a trigger in the schema keeps it from being unset).

A cycle that ends (done, failed, or interrupted at recovery) gets ``ended_at``, its end stamp (:func:`end_stamp`): the
store's clock, but never before the latest end stamp, so a wall clock stepped back does not stamp it into a time window
an MES already exported (:mod:`cellctl.store.parts`).
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
from collections.abc import Mapping
from datetime import datetime, timedelta
from typing import Any

from cellctl.domain import CycleStep
from cellctl.store.connection import Database, dt, from_json, need, to_json, ts
from cellctl.store.records import (
    CycleRecord,
    CycleRequest,
    CycleState,
    CycleStateError,
    IdempotencyConflict,
    IdempotencyInFlight,
    ImageRef,
    InstallAlreadyStarted,
    StepRecord,
    StoredResponse,
    StoreError,
    SubmitResult,
    UnknownCycle,
)


class CycleRows(Database):
    """The cycle, step, image and idempotency-key methods of :class:`cellctl.store.db.CellStore`."""

    # -- cycles -------------------------------------------------------------------------------

    def submit_cycle(self, request: CycleRequest, *, scope: str, key: str, actor: str) -> SubmitResult:
        """Queue a cycle under an idempotency key.

        Same key (in the same scope) and same request: the cycle made the first time
        (``created`` False). Same key, different request: :class:`IdempotencyConflict`.
        """
        need("scope", scope)
        need("idempotency key", key)
        need("actor", actor)
        identity = request.identity()
        digest = _hash_request(identity)
        now = ts(self._clock())
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
        self._transition(cycle_id, "queued", "state = 'running', started_at = ?", (ts(self._clock()),), "start")
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
                c.execute("UPDATE cycles SET install_started_at = ? WHERE id = ?", (ts(now), cycle_id))
            attempt = 1 + c.execute(
                "SELECT COUNT(*) FROM cycle_steps WHERE cycle_id = ? AND step = ?", (cycle_id, int(step))
            ).fetchone()[0]
            c.execute("UPDATE cycles SET current_step = ? WHERE id = ?", (int(step), cycle_id))
            c.execute(
                "INSERT INTO cycle_steps (cycle_id, step, attempt, started_at) VALUES (?, ?, ?, ?)",
                (cycle_id, int(step), attempt, ts(now)),
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
        duration_s: float | None = None,
    ) -> StepRecord:
        """Close the latest attempt of ``step`` with its figures (any JSON-able mapping; numpy ok).

        ``duration_s``: the step's time on a monotonic clock (the recorder's); without it, finished minus
        started on the store's wall clock, never below 0 (a clock stepped back in between would make it negative).
        """
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
            duration = max(0.0, (now - started).total_seconds()) if duration_s is None else float(duration_s)
            c.execute(
                "UPDATE cycle_steps SET finished_at = ?, duration_s = ?, ok = ?, figures_json = ?, error = ? "
                "WHERE id = ?",
                (ts(now), duration, int(bool(ok)), fig_json, error, row[0]),
            )
        return StepRecord(step, int(row[1]), started, now, duration, bool(ok), json.loads(fig_json), error)

    def add_image(
        self,
        cycle_id: int,
        step: CycleStep,
        *,
        name: str,
        uri: str,
        sha256: str | None = None,
        size_bytes: int | None = None,
    ) -> ImageRef:
        """Reference an image saved elsewhere (the store keeps the reference, not the pixels).

        ``sha256`` (64 hex digits) and ``size_bytes`` describe the file as written: the record's
        proof of what the image was (``GET /parts`` checks the file against them).
        """
        need("image name", name)
        need("image uri", uri)
        digest = _check_digest(sha256, size_bytes)
        now = self._clock()
        with self._tx() as c:
            self._cycle_state(c, cycle_id)
            c.execute(
                "INSERT INTO cycle_images (cycle_id, step, name, uri, created_at, sha256, size_bytes) "
                "VALUES (?, ?, ?, ?, ?, ?, ?)",
                (cycle_id, int(CycleStep(step)), name, uri, ts(now), digest, size_bytes),
            )
        return ImageRef(CycleStep(step), name, uri, now, sha256=digest, size_bytes=size_bytes)

    def complete_cycle(
        self, cycle_id: int, *, result: Mapping[str, Any], true_error: Mapping[str, Any] | None = None
    ) -> CycleRecord:
        """running -> done, with the result (and, in simulation, the true error)."""
        now = self._clock()
        self._transition(
            cycle_id,
            "running",
            "state = 'done', finished_at = ?, current_step = 0, result_json = ?, true_error_json = ?",
            (ts(now), to_json("result", dict(result)), _opt_json("true_error", true_error)),
            "complete",
            ends=now,
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
        need("error", error)
        now = self._clock()
        self._transition(
            cycle_id,
            ("queued", "running"),
            "state = 'failed', finished_at = ?, error = ?, result_json = ?, true_error_json = ?",
            (ts(now), error, _opt_json("result", result), _opt_json("true_error", true_error)),
            "fail",
            ends=now,
        )
        return self.cycle(cycle_id)

    def resume_cycle(self, cycle_id: int) -> CycleRecord:
        """interrupted -> running, only if its install never started (else InstallAlreadyStarted).

        The interrupted step stays recorded; the orchestrator decides where to pick up (typically
        re-measuring from align, since the car or the robot may have moved). It has not ended any more: its end
        stamp is cleared until it ends again.
        """
        with self._tx() as c:
            state, install_started = self._cycle_state(c, cycle_id)
            if state != CycleState.INTERRUPTED:
                raise CycleStateError(cycle_id, f"is {state.value}; only an interrupted cycle can be resumed")
            if install_started is not None:
                raise InstallAlreadyStarted(cycle_id, install_started)
            c.execute(
                "UPDATE cycles SET state = 'running', current_step = 0, error = NULL, ended_at = NULL WHERE id = ?",
                (cycle_id,),
            )
        return self.cycle(cycle_id)

    def cycle(self, cycle_id: int) -> CycleRecord:
        """One cycle with its steps and images (UnknownCycle if there is none)."""
        row = self._conn.execute(f"SELECT {CYCLE_COLUMNS} FROM cycles WHERE id = ?", (cycle_id,)).fetchone()
        if row is None:
            raise UnknownCycle(cycle_id)
        return full_cycle(self._conn, row)

    def cycles(
        self, *, limit: int = 50, before_id: int | None = None, state: CycleState | None = None
    ) -> list[CycleRecord]:
        """Newest first, without steps and images (fetch one with :meth:`cycle` for those)."""
        if not (1 <= limit <= 1000):
            raise ValueError(f"limit must be in 1..1000, got {limit}")
        where: list[str] = []
        args: list[Any] = []
        if before_id is not None:
            where.append("id < ?")
            args.append(before_id)
        if state is not None:
            where.append("state = ?")
            args.append(CycleState(state).value)
        sql = f"SELECT {CYCLE_COLUMNS} FROM cycles"
        if where:
            sql += " WHERE " + " AND ".join(where)
        sql += " ORDER BY id DESC LIMIT ?"
        return [_cycle_from_row(r, (), ()) for r in self._conn.execute(sql, (*args, limit))]

    def count_finished(self, state: CycleState, *, since: datetime) -> int:
        """How many cycles in ``state`` finished at or after ``since`` (counted in SQL, however many)."""
        row = self._conn.execute(
            "SELECT COUNT(*) FROM cycles WHERE state = ? AND finished_at >= ?", (CycleState(state).value, ts(since))
        ).fetchone()
        return int(row[0])

    def newest_cycle(self, *, at_most_id: int | None = None) -> tuple[int, datetime] | None:
        """The newest cycle by id (of those up to ``at_most_id``): its id and creation time, or None if none."""
        row = self._conn.execute(
            "SELECT id, created_at FROM cycles WHERE id <= ? ORDER BY id DESC LIMIT 1",
            (2**63 - 1 if at_most_id is None else int(at_most_id),),
        ).fetchone()
        return None if row is None else (int(row[0]), datetime.fromisoformat(row[1]))

    def cycle_counts(self) -> dict[CycleState, int]:
        """How many cycles are in each state (every state listed, 0 included)."""
        counts = {s: 0 for s in CycleState}
        for state, n in self._conn.execute("SELECT state, COUNT(*) FROM cycles GROUP BY state"):
            counts[CycleState(state)] = int(n)
        return counts

    # -- idempotency of other requests (commands) ---------------------------------------------

    def claim_key(self, scope: str, key: str, request: Mapping[str, Any]) -> StoredResponse | None:
        """Start an idempotent request. None: first time, go ahead and :meth:`complete_key` after.
        A StoredResponse: replay it. Raises IdempotencyInFlight (the first is still running) or
        IdempotencyConflict (same key, different request)."""
        need("scope", scope)
        need("idempotency key", key)
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
                    (scope, key, digest, req_json, ts(self._clock())),
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
        """Store the answer of a claimed request, to replay to its retries."""
        with self._tx() as c:
            n = c.execute(
                "UPDATE idempotency_keys SET response_json = ?, completed_at = ? "
                "WHERE scope = ? AND key = ? AND response_json IS NULL AND cycle_id IS NULL",
                (to_json("response", dict(response)), ts(self._clock()), scope, key),
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
                (scope, ts(created_before)),
            ).rowcount

    # -- internals ----------------------------------------------------------------------------

    def _cycle_state(self, c: sqlite3.Connection, cycle_id: int) -> tuple[CycleState, datetime | None]:
        row = c.execute("SELECT state, install_started_at FROM cycles WHERE id = ?", (cycle_id,)).fetchone()
        if row is None:
            raise UnknownCycle(cycle_id)
        return CycleState(row[0]), dt(row[1])

    def _transition(
        self,
        cycle_id: int,
        from_states: str | tuple[str, ...],
        set_sql: str,
        args: tuple[Any, ...],
        verb: str,
        *,
        ends: datetime | None = None,
    ) -> None:
        """``ends``: the cycle ends at this time of the store's clock, and gets its :func:`end_stamp` in the same
        transaction."""
        allowed = (from_states,) if isinstance(from_states, str) else from_states
        with self._tx() as c:
            state, _ = self._cycle_state(c, cycle_id)
            if state.value not in allowed:
                raise CycleStateError(
                    cycle_id, f"is {state.value}; it can {verb} only when {' or '.join(allowed)}"
                )
            if ends is not None:
                set_sql, args = f"{set_sql}, ended_at = ?", (*args, end_stamp(c, ends))
            c.execute(f"UPDATE cycles SET {set_sql} WHERE id = ?", (*args, cycle_id))


END_STEP = timedelta(microseconds=1)
"""The least step between end stamps (the stored resolution)."""


def latest_end(c: sqlite3.Connection) -> datetime | None:
    """The latest end stamp the store gave (UTC; before any cycle ended, the floor an export's bound set less 1 us), None
    before either: one row read, however many cycles."""
    row = c.execute("SELECT ended_at FROM cycle_end_mark WHERE id = 1").fetchone()
    return None if row is None else dt(row[0])


def end_stamp(c: sqlite3.Connection, now: datetime) -> str:
    """The end stamp (stored text) of cycles ending ``now`` in the open write transaction ``c``, kept as the latest.

    It is ``now`` (the store's wall clock), but never earlier than the latest end stamp + :data:`END_STEP`: a clock
    stepped back (NTP) does not stamp an end before one already given, so an export bound no later than the latest
    end stamp + :data:`END_STEP` has every later end at or after it.
    """
    latest = latest_end(c)
    stamp = ts(now if latest is None else max(now, latest + END_STEP))
    c.execute("INSERT INTO cycle_end_mark (id, ended_at) VALUES (1, :t) ON CONFLICT (id) DO UPDATE SET ended_at = :t",
              {"t": stamp})  # fmt: skip
    return stamp


def _hash_request(identity: Mapping[str, Any]) -> str:
    return hashlib.sha256(to_json("request", identity).encode()).hexdigest()


def _opt_json(what: str, obj: Mapping[str, Any] | None) -> str | None:
    return None if obj is None else to_json(what, dict(obj))


def _check_digest(sha256: str | None, size_bytes: int | None) -> str | None:
    """An image's SHA-256 as stored (lower-case hex), refusing a malformed one or a negative size."""
    if size_bytes is not None and (isinstance(size_bytes, bool) or not isinstance(size_bytes, int) or size_bytes < 0):
        raise ValueError(f"image size_bytes must be a whole number of bytes, 0 or more, got {size_bytes!r}")
    if sha256 is None:
        return None
    digest = sha256.lower() if isinstance(sha256, str) else ""
    if len(digest) != 64 or any(ch not in "0123456789abcdef" for ch in digest):
        raise ValueError(f"image sha256 must be 64 hexadecimal digits, got {sha256!r}")
    return digest


CYCLE_COLUMNS = (
    "id, idempotency_scope, idempotency_key, recipe, part_id, car_id, source, actor, state, current_step, "
    "result_json, error, true_error_json, created_at, started_at, finished_at, install_started_at, "
    "interrupted_step, interrupted_at, (SELECT k.request_json FROM idempotency_keys k WHERE k.scope = "
    "cycles.idempotency_scope AND k.key = cycles.idempotency_key AND k.cycle_id = cycles.id)"
)
"""The columns of ``cycles`` that :func:`full_cycle` reads, in its order; last, its key's stored request (the PLC's
recipe_id: :attr:`CycleRequest.plc_recipe_id`)."""


def full_cycle(conn: sqlite3.Connection, row: tuple[Any, ...]) -> CycleRecord:
    """A ``cycles`` row (:data:`CYCLE_COLUMNS`) as its record with its steps and images."""
    cycle_id = int(row[0])
    steps = tuple(
        StepRecord(CycleStep(r[0]), r[1], datetime.fromisoformat(r[2]), dt(r[3]), r[4],
                   None if r[5] is None else bool(r[5]), json.loads(r[6]), r[7])  # fmt: skip
        for r in conn.execute(
            "SELECT step, attempt, started_at, finished_at, duration_s, ok, figures_json, error "
            "FROM cycle_steps WHERE cycle_id = ? ORDER BY id",
            (cycle_id,),
        )
    )
    images = tuple(
        ImageRef(CycleStep(r[0]), r[1], r[2], datetime.fromisoformat(r[3]), dt(r[4]), r[5], r[6], r[7])
        for r in conn.execute(
            "SELECT step, name, uri, created_at, pruned_at, pruned_reason, sha256, size_bytes FROM cycle_images "
            "WHERE cycle_id = ? ORDER BY id",
            (cycle_id,),
        )
    )
    return _cycle_from_row(row, steps, images)


def _cycle_from_row(r: tuple[Any, ...], steps: tuple[StepRecord, ...], images: tuple[ImageRef, ...]) -> CycleRecord:
    return CycleRecord(
        id=int(r[0]),
        idempotency_scope=r[1],
        idempotency_key=r[2],
        request=CycleRequest(recipe=r[3], part_id=r[4], car_id=r[5], source=r[6]).with_stored(r[19]),
        actor=r[7],
        state=CycleState(r[8]),
        current_step=CycleStep(r[9]),
        result=from_json(r[10]),
        error=r[11],
        true_error=from_json(r[12]),
        created_at=datetime.fromisoformat(r[13]),
        started_at=dt(r[14]),
        finished_at=dt(r[15]),
        install_started_at=dt(r[16]),
        interrupted_step=None if r[17] is None else CycleStep(r[17]),
        interrupted_at=dt(r[18]),
        steps=steps,
        images=images,
    )
