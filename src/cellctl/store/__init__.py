"""SQLite persistence of the cell: cycles, alarms, audit log, idempotency keys, calibration history."""

from cellctl.store.aio import AsyncCellStore
from cellctl.store.db import CellStore, StoreInfo
from cellctl.store.jobs import JobRecord, UnknownJob
from cellctl.store.retention import DatabaseSize, KeptImage
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
    SchemaTooNew,
    StepRecord,
    StoredResponse,
    StoreError,
    SubmitResult,
    UnknownCycle,
)

__all__ = [
    "AsyncCellStore",
    "AuditChainBroken",
    "AuditEntry",
    "CalibrationVersion",
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
