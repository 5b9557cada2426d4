"""The store for asyncio code: every call runs on one dedicated thread that owns the connection.

Why one thread rather than ``asyncio.to_thread`` plus a lock: sqlite3 connections belong to the
thread that made them (the module checks it), a single thread serialises all writes in the order
they were submitted (the audit log's order is the order of events), and the event loop never
blocks on a disk sync. The cell writes a few rows per second; one thread is plenty.

A call whose awaiting task is cancelled still runs to its end on the store thread (a started
write is never half done). For the install marker this means: if ``await begin_step(..., INSTALL)``
did not return normally, do not command the robot.
"""

from __future__ import annotations

import asyncio
import functools
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime
from pathlib import Path
from typing import Any, TypeVar

from cellctl.cell.alarms import Alarm
from cellctl.cell.packml import MachineEvent
from cellctl.cell.tags import CycleStep
from cellctl.store.db import CellStore, StoreInfo, Synchronous, _utcnow
from cellctl.store.jobs import JobRecord
from cellctl.store.retention import DatabaseSize, KeptImage
from cellctl.store.records import (
    AuditEntry,
    CalibrationVersion,
    CycleRecord,
    CycleRequest,
    CycleState,
    ImageRef,
    RecoveryReport,
    StepRecord,
    StoredResponse,
    SubmitResult,
)

R = TypeVar("R")


class AsyncCellStore:
    """Open with ``await AsyncCellStore.open(path)``; ``await close()`` at shutdown."""

    def __init__(self, store: CellStore, executor: ThreadPoolExecutor) -> None:
        self._store = store
        self._executor = executor
        self._closed = False

    @classmethod
    async def open(
        cls,
        path: str | Path,
        *,
        synchronous: Synchronous = "FULL",
        busy_timeout_s: float = 5.0,
        clock: Callable[[], datetime] = _utcnow,
    ) -> AsyncCellStore:
        executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cellctl-store")
        try:
            store = await asyncio.get_running_loop().run_in_executor(
                executor,
                functools.partial(
                    CellStore.open, path, synchronous=synchronous, busy_timeout_s=busy_timeout_s, clock=clock
                ),
            )
        except BaseException:
            executor.shutdown(wait=False)
            raise
        return cls(store, executor)

    async def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        await asyncio.get_running_loop().run_in_executor(self._executor, self._store.close)
        self._executor.shutdown(wait=True)

    async def _run(self, fn: Callable[..., R], *args: Any, **kwargs: Any) -> R:
        if self._closed:
            raise RuntimeError("the store is closed")
        return await asyncio.get_running_loop().run_in_executor(self._executor, functools.partial(fn, *args, **kwargs))

    async def info(self) -> StoreInfo:
        return await self._run(self._store.info)

    async def recover(self) -> RecoveryReport:
        return await self._run(self._store.recover)

    # cycles
    async def submit_cycle(self, request: CycleRequest, *, scope: str, key: str, actor: str) -> SubmitResult:
        return await self._run(self._store.submit_cycle, request, scope=scope, key=key, actor=actor)

    async def cycle_for_key(self, scope: str, key: str) -> CycleRecord | None:
        return await self._run(self._store.cycle_for_key, scope, key)

    async def start_cycle(self, cycle_id: int) -> CycleRecord:
        return await self._run(self._store.start_cycle, cycle_id)

    async def begin_step(self, cycle_id: int, step: CycleStep) -> StepRecord:
        return await self._run(self._store.begin_step, cycle_id, step)

    async def finish_step(
        self, cycle_id: int, step: CycleStep, *, ok: bool, figures: Mapping[str, Any], error: str | None = None
    ) -> StepRecord:
        return await self._run(self._store.finish_step, cycle_id, step, ok=ok, figures=figures, error=error)

    async def add_image(self, cycle_id: int, step: CycleStep, *, name: str, uri: str) -> ImageRef:
        return await self._run(self._store.add_image, cycle_id, step, name=name, uri=uri)

    async def complete_cycle(
        self, cycle_id: int, *, result: Mapping[str, Any], true_error: Mapping[str, Any] | None = None
    ) -> CycleRecord:
        return await self._run(self._store.complete_cycle, cycle_id, result=result, true_error=true_error)

    async def fail_cycle(
        self,
        cycle_id: int,
        *,
        error: str,
        result: Mapping[str, Any] | None = None,
        true_error: Mapping[str, Any] | None = None,
    ) -> CycleRecord:
        return await self._run(self._store.fail_cycle, cycle_id, error=error, result=result, true_error=true_error)

    async def resume_cycle(self, cycle_id: int) -> CycleRecord:
        return await self._run(self._store.resume_cycle, cycle_id)

    async def cycle(self, cycle_id: int) -> CycleRecord:
        return await self._run(self._store.cycle, cycle_id)

    async def cycles(
        self, *, limit: int = 50, before_id: int | None = None, state: CycleState | None = None
    ) -> list[CycleRecord]:
        return await self._run(self._store.cycles, limit=limit, before_id=before_id, state=state)

    async def cycle_counts(self) -> dict[CycleState, int]:
        return await self._run(self._store.cycle_counts)

    # idempotency of other requests
    async def claim_key(self, scope: str, key: str, request: Mapping[str, Any]) -> StoredResponse | None:
        return await self._run(self._store.claim_key, scope, key, request)

    async def complete_key(self, scope: str, key: str, response: Mapping[str, Any]) -> None:
        await self._run(self._store.complete_key, scope, key, response)

    async def release_key(self, scope: str, key: str) -> None:
        await self._run(self._store.release_key, scope, key)

    async def forget_keys(self, scope: str, *, created_before: datetime) -> int:
        return await self._run(self._store.forget_keys, scope, created_before=created_before)

    # alarms
    async def save_alarm(self, alarm: Alarm) -> None:
        await self._run(self._store.save_alarm, alarm)

    async def alarms(self, *, active_only: bool = False, limit: int = 100) -> list[Alarm]:
        return await self._run(self._store.alarms, active_only=active_only, limit=limit)

    # audit
    async def append_audit(
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
        return await self._run(
            self._store.append_audit, actor=actor, source=source, action=action, params=params,
            state_before=state_before, state_after=state_after, result=result, cycle_id=cycle_id, at=at,
        )  # fmt: skip

    async def append_machine_event(self, event: MachineEvent, *, cycle_id: int | None = None) -> AuditEntry:
        return await self._run(self._store.append_machine_event, event, cycle_id=cycle_id)

    async def audit_entries(self, *, after_seq: int = 0, limit: int = 100) -> list[AuditEntry]:
        return await self._run(self._store.audit_entries, after_seq=after_seq, limit=limit)

    async def verify_audit_chain(self) -> int:
        return await self._run(self._store.verify_audit_chain)

    # calibration
    async def save_calibration(
        self, kind: str, data: Mapping[str, Any], *, metadata: Mapping[str, Any], created_by: str
    ) -> CalibrationVersion:
        return await self._run(self._store.save_calibration, kind, data, metadata=metadata, created_by=created_by)

    async def calibration(self, kind: str, version: int | None = None) -> CalibrationVersion | None:
        return await self._run(self._store.calibration, kind, version)

    async def calibration_history(self, kind: str) -> list[CalibrationVersion]:
        return await self._run(self._store.calibration_history, kind)

    async def calibration_kinds(self) -> list[str]:
        return await self._run(self._store.calibration_kinds)

    # commissioning jobs
    async def create_job(
        self, procedure: str, *, actor: str, source: str, options: Mapping[str, Any], version_before: int | None
    ) -> JobRecord:
        return await self._run(
            self._store.create_job, procedure, actor=actor, source=source, options=options, version_before=version_before
        )

    async def update_job(self, job_id: int, **fields: Any) -> JobRecord:
        """See :meth:`cellctl.store.jobs.JobRows.update_job` for the fields."""
        return await self._run(self._store.update_job, job_id, **fields)

    async def job(self, job_id: int) -> JobRecord:
        return await self._run(self._store.job, job_id)

    async def jobs(self, *, limit: int = 50, procedure: str | None = None) -> list[JobRecord]:
        return await self._run(self._store.jobs, limit=limit, procedure=procedure)

    async def recover_jobs(self) -> list[int]:
        return await self._run(self._store.recover_jobs)

    # retention
    async def kept_images(self) -> list[KeptImage]:
        return await self._run(self._store.kept_images)

    async def mark_images_pruned(self, uris: Sequence[str], *, reason: str, at: datetime | None = None) -> int:
        return await self._run(self._store.mark_images_pruned, uris, reason=reason, at=at)

    async def pruned_only(self, uris: Sequence[str]) -> set[str]:
        return await self._run(self._store.pruned_only, uris)

    async def prune_cycles(self, *, created_before: datetime, batch: int = 500) -> tuple[list[int], list[str]]:
        return await self._run(self._store.prune_cycles, created_before=created_before, batch=batch)

    async def prune_alarms(self, *, raised_before: datetime) -> int:
        return await self._run(self._store.prune_alarms, raised_before=raised_before)

    async def oldest_cycle(self) -> datetime | None:
        return await self._run(self._store.oldest_cycle)

    async def database_size(self, *, per_table: bool = False) -> DatabaseSize:
        return await self._run(self._store.database_size, per_table=per_table)

    async def checkpoint(self) -> None:
        await self._run(self._store.checkpoint)
