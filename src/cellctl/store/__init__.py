"""SQLite persistence of the cell: cycles, alarms, audit log, idempotency keys, commissioning jobs,
the closed-loop offset's state and history.

Open :class:`CellStore` (synchronous, one thread) or, from asyncio, :class:`AsyncCellStore` (every
call on the store's own thread). The store keeps the values of :mod:`cellctl.domain` and never
imports the cell (an import contract in pyproject.toml holds it to that).
"""

from cellctl.store.aio import AsyncCellStore
from cellctl.store.db import CellStore, StoreInfo
from cellctl.store.jobs import JobRecord, UnknownJob
from cellctl.store import records
from cellctl.store.records import *  # noqa: F403 - the records are the package's vocabulary
from cellctl.store.retention import DatabaseSize, KeptImage
from cellctl.store.spc import ALL_RECIPES, SpcDuplicateCycle, SpcHistoryRow

__all__ = [
    "ALL_RECIPES",
    "AsyncCellStore",
    "CellStore",
    "DatabaseSize",
    "JobRecord",
    "KeptImage",
    "SpcDuplicateCycle",
    "SpcHistoryRow",
    "StoreInfo",
    "UnknownJob",
    *records.__all__,
]
