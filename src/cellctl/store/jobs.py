"""Commissioning jobs in the store: one row per calibration, teaching or verification job.

A job row says which procedure ran, who started it and from where, with which options, the plan
it showed, how far it got, the dataset it wrote (complete or partial), its result or the reason
it ended, and the calibration-set version before and after. Rows left ``running`` by a process
that died become ``interrupted`` at the next start (:meth:`JobRows.recover_jobs`). The table is
migration 2 of :mod:`cellctl.store.schema`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Literal

from cellctl.store.connection import Database, dt, from_json, to_json, ts
from cellctl.store.records import StoreError

JobState = Literal["running", "computing", "done", "refused", "failed", "cancelled", "interrupted"]
JOB_STATES: tuple[str, ...] = ("running", "computing", "done", "refused", "failed", "cancelled", "interrupted")
FINISHED_JOB_STATES = frozenset({"done", "refused", "failed", "cancelled", "interrupted"})


class UnknownJob(StoreError):
    """No job with that id."""


@dataclass(frozen=True)
class JobRecord:
    """One commissioning job as stored."""

    id: int
    procedure: str
    state: str
    actor: str
    source: str
    options: dict[str, Any]
    plan: dict[str, Any] | None
    progress: dict[str, Any] | None
    dataset: str | None
    result: dict[str, Any] | None
    error: str | None
    version_before: int | None
    version_after: int | None
    created_at: datetime
    finished_at: datetime | None

    @property
    def finished(self) -> bool:
        return self.state in FINISHED_JOB_STATES


_COLUMNS = (
    "id, procedure, state, actor, source, options_json, plan_json, progress_json, dataset, result_json, "
    "error, version_before, version_after, created_at, finished_at"
)


def _row(r: tuple[Any, ...]) -> JobRecord:
    return JobRecord(
        int(r[0]), r[1], r[2], r[3], r[4], json.loads(r[5]), from_json(r[6]), from_json(r[7]), r[8],
        from_json(r[9]), r[10], None if r[11] is None else int(r[11]), None if r[12] is None else int(r[12]),
        datetime.fromisoformat(r[13]), dt(r[14]),
    )  # fmt: skip


class JobRows(Database):
    """The job methods of :class:`cellctl.store.db.CellStore`."""

    def create_job(
        self, procedure: str, *, actor: str, source: str, options: Mapping[str, Any], version_before: int | None
    ) -> JobRecord:
        """A new job, ``running`` from now."""
        with self._tx() as c:
            cur = c.execute(
                "INSERT INTO jobs (procedure, state, actor, source, options_json, version_before, created_at) "
                "VALUES (?, 'running', ?, ?, ?, ?, ?)",
                (procedure, actor, source, to_json("options", dict(options)), version_before, ts(self._clock())),
            )
            job_id = int(cur.lastrowid or 0)
        return self.job(job_id)

    def update_job(
        self,
        job_id: int,
        *,
        state: str | None = None,
        plan: Mapping[str, Any] | None = None,
        progress: Mapping[str, Any] | None = None,
        dataset: str | None = None,
        result: Mapping[str, Any] | None = None,
        error: str | None = None,
        version_after: int | None = None,
    ) -> JobRecord:
        """Change the given fields; a finishing state stamps ``finished_at``. A finished job cannot change state."""
        if state is not None and state not in JOB_STATES:
            raise ValueError(f"state must be one of {', '.join(JOB_STATES)}, got {state!r}")
        sets: list[str] = []
        args: list[Any] = []
        for column, value in (
            ("plan_json", None if plan is None else to_json("plan", dict(plan))),
            ("progress_json", None if progress is None else to_json("progress", dict(progress))),
            ("dataset", dataset),
            ("result_json", None if result is None else to_json("result", dict(result))),
            ("error", error),
            ("version_after", version_after),
        ):
            if value is not None:
                sets.append(f"{column} = ?")
                args.append(value)
        with self._tx() as c:
            row = c.execute("SELECT state FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is None:
                raise UnknownJob(f"no job {job_id}")
            if state is not None:
                if row[0] in FINISHED_JOB_STATES and state != row[0]:
                    raise StoreError(f"job {job_id} has ended ({row[0]}); it cannot become {state}")
                sets.append("state = ?")
                args.append(state)
                if state in FINISHED_JOB_STATES:
                    sets.append("finished_at = ?")
                    args.append(ts(self._clock()))
            if sets:
                c.execute(f"UPDATE jobs SET {', '.join(sets)} WHERE id = ?", (*args, job_id))
        return self.job(job_id)

    def job(self, job_id: int) -> JobRecord:
        r = self._conn.execute(f"SELECT {_COLUMNS} FROM jobs WHERE id = ?", (job_id,)).fetchone()
        if r is None:
            raise UnknownJob(f"no job {job_id}")
        return _row(r)

    def jobs(self, *, limit: int = 50, procedure: str | None = None) -> list[JobRecord]:
        """The newest jobs first."""
        where, args = ("WHERE procedure = ?", (procedure,)) if procedure else ("", ())
        rows = self._conn.execute(f"SELECT {_COLUMNS} FROM jobs {where} ORDER BY id DESC LIMIT ?", (*args, int(limit))).fetchall()
        return [_row(r) for r in rows]

    def recover_jobs(self) -> list[int]:
        """Mark jobs a dead process left running as ``interrupted``; returns their ids."""
        with self._tx() as c:
            ids = [int(r[0]) for r in c.execute("SELECT id FROM jobs WHERE state IN ('running', 'computing')").fetchall()]
            c.execute(
                "UPDATE jobs SET state = 'interrupted', finished_at = ?, "
                "error = COALESCE(error, 'interrupted: the service stopped while the job ran; "
                "what it had collected was not kept: start the job again') "
                "WHERE state IN ('running', 'computing')",
                (ts(self._clock()),),
            )
        return ids

