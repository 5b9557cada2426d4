"""SQLite persistence of the cell: cycles, alarms, audit log, idempotency keys, commissioning jobs.

Open :class:`CellStore` (synchronous, one thread) or, from asyncio, :class:`AsyncCellStore` (every
call on the store's own thread). The store keeps the values of :mod:`cellctl.domain` and never
imports the cell (an import contract in pyproject.toml holds it to that).
"""

from cellctl.store.aio import AsyncCellStore
from cellctl.store.db import CellStore, StoreInfo
from cellctl.store.jobs import JobRecord, UnknownJob
from cellctl.store.records import (
    AuditChainBroken,
    AuditEntry,
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
    SchemaTooNew,
    StepRecord,
    StoredResponse,
    StoreError,
    SubmitResult,
    UnknownCycle,
)
from cellctl.store.retention import DatabaseSize, KeptImage

__all__ = [
    "AsyncCellStore",
    "AuditChainBroken",
    "AuditEntry",
    "CellStore",
    "CycleRecord",
    "CycleRequest",
    "CycleState",
    "CycleStateError",
    "DatabaseSize",
    "IdempotencyConflict",
    "IdempotencyInFlight",
    "ImageRef",
    "InstallAlreadyStarted",
    "InterruptedCycle",
    "JobRecord",
    "KeptImage",
    "RecoveryReport",
    "SchemaTooNew",
    "StepRecord",
    "StoreError",
    "StoreInfo",
    "StoredResponse",
    "SubmitResult",
    "UnknownCycle",
    "UnknownJob",
]
