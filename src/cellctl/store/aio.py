"""The store for asyncio code: every call runs on one dedicated thread that owns the connection.

Why one thread rather than ``asyncio.to_thread`` plus a lock: sqlite3 connections belong to the
thread that made them (the module checks it), a single thread serialises all writes in the order
they were submitted (the audit log's order is the order of events), and the event loop never
blocks on a disk sync. The cell writes a few rows per second; one thread is plenty.

Each async method of :class:`AsyncCellStore` is the :class:`~cellctl.store.db.CellStore` method
of the same name run through :meth:`AsyncCellStore.call` on that thread, with the same
parameters and result (:func:`_on_store_thread` carries the signature over for type checkers).
Calls wait for nothing but each other; a write blocked by another connection's lock waits up to
``busy_timeout_s`` (seconds) and then raises ``sqlite3.OperationalError``. A call after
:meth:`AsyncCellStore.close` raises ``RuntimeError``; the store's own errors pass through as raised.

A call whose awaiting task is cancelled still runs to its end on the store thread (a started
write is never half done). For the install marker this means: if ``await begin_step(..., INSTALL)``
did not return normally, do not command the robot.
"""

from __future__ import annotations

import asyncio
import functools
from collections.abc import Callable, Coroutine
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime
from pathlib import Path
from typing import Any, Concatenate, ParamSpec, TypeVar

from cellctl.store.connection import Synchronous, utcnow
from cellctl.store.db import CellStore
from cellctl.store.upgrade import StoreUpgrade

P = ParamSpec("P")
R = TypeVar("R")


def _on_store_thread(
    method: Callable[Concatenate[CellStore, P], R],
) -> Callable[Concatenate[AsyncCellStore, P], Coroutine[Any, Any, R]]:
    """The async method of :class:`AsyncCellStore` that runs ``method`` (a :class:`CellStore`
    method) on the store thread: same name, parameters, result and docstring."""
    name = method.__name__

    async def on_store_thread(self: AsyncCellStore, /, *args: P.args, **kwargs: P.kwargs) -> R:
        # Looked up by name at each call, so the method run is the store's own (a subclass's or a test's patch).
        sync: Callable[P, R] = getattr(self._store, name)
        return await self.call(sync, *args, **kwargs)

    on_store_thread.__name__ = name
    on_store_thread.__qualname__ = f"AsyncCellStore.{name}"
    on_store_thread.__doc__ = method.__doc__
    return on_store_thread


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
        clock: Callable[[], datetime] = utcnow,
    ) -> AsyncCellStore:
        """Open the store on a new store thread (see :meth:`CellStore.open` for the arguments)."""
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

    @property
    def upgrade(self) -> StoreUpgrade | None:
        """The migration opening did on a store of an earlier release, with the copy it kept (else None)."""
        return self._store.upgrade

    async def close(self) -> None:
        """Close the connection on its thread, then end the thread. A second close does nothing."""
        if self._closed:
            return
        self._closed = True
        await asyncio.get_running_loop().run_in_executor(self._executor, self._store.close)
        self._executor.shutdown(wait=True)

    async def call(self, fn: Callable[P, R], /, *args: P.args, **kwargs: P.kwargs) -> R:
        """``fn(*args, **kwargs)`` on the store thread, after every call submitted before it."""
        if self._closed:
            raise RuntimeError("the store is closed")
        return await asyncio.get_running_loop().run_in_executor(self._executor, functools.partial(fn, *args, **kwargs))

    info = _on_store_thread(CellStore.info)
    recover = _on_store_thread(CellStore.recover)
    unacknowledged_alarms = _on_store_thread(CellStore.unacknowledged_alarms)

    # cycles, steps, images (CycleRows)
    submit_cycle = _on_store_thread(CellStore.submit_cycle)
    cycle_for_key = _on_store_thread(CellStore.cycle_for_key)
    start_cycle = _on_store_thread(CellStore.start_cycle)
    begin_step = _on_store_thread(CellStore.begin_step)
    finish_step = _on_store_thread(CellStore.finish_step)
    add_image = _on_store_thread(CellStore.add_image)
    complete_cycle = _on_store_thread(CellStore.complete_cycle)
    fail_cycle = _on_store_thread(CellStore.fail_cycle)
    resume_cycle = _on_store_thread(CellStore.resume_cycle)
    cycle = _on_store_thread(CellStore.cycle)
    cycles = _on_store_thread(CellStore.cycles)
    cycle_counts = _on_store_thread(CellStore.cycle_counts)
    count_finished = _on_store_thread(CellStore.count_finished)
    newest_cycle = _on_store_thread(CellStore.newest_cycle)

    # idempotency of other requests (CycleRows)
    claim_key = _on_store_thread(CellStore.claim_key)
    complete_key = _on_store_thread(CellStore.complete_key)
    release_key = _on_store_thread(CellStore.release_key)
    forget_keys = _on_store_thread(CellStore.forget_keys)

    # alarms (AlarmRows)
    save_alarm = _on_store_thread(CellStore.save_alarm)
    alarms = _on_store_thread(CellStore.alarms)

    # audit (AuditRows)
    append_audit = _on_store_thread(CellStore.append_audit)
    append_machine_event = _on_store_thread(CellStore.append_machine_event)
    audit_entries = _on_store_thread(CellStore.audit_entries)
    verify_audit_chain = _on_store_thread(CellStore.verify_audit_chain)

    # commissioning jobs (JobRows)
    create_job = _on_store_thread(CellStore.create_job)
    update_job = _on_store_thread(CellStore.update_job)
    job = _on_store_thread(CellStore.job)
    jobs = _on_store_thread(CellStore.jobs)
    recover_jobs = _on_store_thread(CellStore.recover_jobs)

    # the closed-loop offset (SpcRows)
    save_spc = _on_store_thread(CellStore.save_spc)
    spc_state = _on_store_thread(CellStore.spc_state)
    spc_states = _on_store_thread(CellStore.spc_states)
    spc_history = _on_store_thread(CellStore.spc_history)
    prune_spc_history = _on_store_thread(CellStore.prune_spc_history)

    # part traceability (PartRows)
    part_installs = _on_store_thread(CellStore.part_installs)
    cycle_actions = _on_store_thread(CellStore.cycle_actions)

    # the MQTT outbox (OutboxRows)
    outbox_enqueue = _on_store_thread(CellStore.outbox_enqueue)
    outbox_next_seq = _on_store_thread(CellStore.outbox_next_seq)
    outbox_pending = _on_store_thread(CellStore.outbox_pending)
    outbox_delete = _on_store_thread(CellStore.outbox_delete)
    outbox_counts = _on_store_thread(CellStore.outbox_counts)
    outbox_drops_reported = _on_store_thread(CellStore.outbox_drops_reported)
    outbox_start_results = _on_store_thread(CellStore.outbox_start_results)
    outbox_result_backlog = _on_store_thread(CellStore.outbox_result_backlog)
    outbox_retained_topics = _on_store_thread(CellStore.outbox_retained_topics)

    # retention (RetentionRows)
    kept_images = _on_store_thread(CellStore.kept_images)
    mark_images_pruned = _on_store_thread(CellStore.mark_images_pruned)
    pruned_only = _on_store_thread(CellStore.pruned_only)
    restore_missing_images = _on_store_thread(CellStore.restore_missing_images)
    prune_cycles = _on_store_thread(CellStore.prune_cycles)
    prune_request_keys = _on_store_thread(CellStore.prune_request_keys)
    prune_alarms = _on_store_thread(CellStore.prune_alarms)
    oldest_cycle = _on_store_thread(CellStore.oldest_cycle)
    database_size = _on_store_thread(CellStore.database_size)
    checkpoint = _on_store_thread(CellStore.checkpoint)
