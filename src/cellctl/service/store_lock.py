"""One service per store: a second ``cellctl serve`` on the same database refuses before it writes to it.

Startup marks every cycle the last run left queued or running as interrupted. A second instance
started by mistake beside a running one (by hand while systemd runs it) would do that to the live
cell's cycle before it found its ports taken. An exclusive ``flock`` on ``<database>.lock``, taken
before the store is opened and held until it is closed, keeps it out; the kernel drops it when the
process dies, so a killed service never leaves a stale lock.
"""

from __future__ import annotations

import os
from pathlib import Path

from cellctl.pidlock import LockHeld, holder, take
from cellctl.store.connection import STORE_PATH_FIX, StorePathError


class StoreInUse(RuntimeError):
    """Another process holds the store; the message names it and what to do."""


class StoreLock:
    """The exclusive lock beside a store's database file (``<name>.lock``, holding the owner's pid)."""

    def __init__(self, db_path: Path) -> None:
        self.db_path = db_path
        self.path = db_path.with_name(db_path.name + ".lock")
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock, or raise StoreInUse naming the process that has it, or StorePathError (naming
        ``[store] path`` and the fix) if the lock file cannot be made or written."""
        try:
            self._fd = take(self.path)
        except LockHeld as held:
            raise StoreInUse(
                f"another cellctl service (pid {held.holder}) is running on the store {self.db_path}: stop it "
                "first, or give this one its own [store] path"
            ) from None
        except OSError as err:
            raise StorePathError(
                f"[store] path {self.db_path}: its lock file {self.path} cannot be made or written "
                f"({err.strerror or err}); give the service's user the right to, or {STORE_PATH_FIX}"
            ) from None

    def holder(self) -> str | None:
        """The pid of the service running on this store now (None: none)."""
        return holder(self.path)

    def release(self) -> None:
        """Let the store go (after it is closed). Idempotent."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
