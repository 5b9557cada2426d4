"""One service per store: a second ``cellctl serve`` on the same database refuses before it writes to it.

Startup marks every cycle the last run left queued or running as interrupted. A second instance
started by mistake beside a running one (by hand while systemd runs it) would do that to the live
cell's cycle before it found its ports taken. An exclusive ``flock`` on ``<database>.lock``, taken
before the store is opened and held until it is closed, keeps it out; the kernel drops it when the
process dies, so a killed service never leaves a stale lock.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path


class StoreInUse(RuntimeError):
    """Another process holds the store; the message names it and what to do."""


class StoreLock:
    """The exclusive lock beside a store's database file (``<name>.lock``, holding the owner's pid)."""

    def __init__(self, db_path: Path) -> None:
        self.path = db_path.with_name(db_path.name + ".lock")
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock, or raise StoreInUse naming the process that has it."""
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise StoreInUse(
                f"another cellctl service (pid {holder}) is running on the store {self.path.with_suffix('')}: stop it "
                "first, or give this one its own [store] path"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd

    def holder(self) -> str | None:
        """The pid of the service running on this store now (None: none; the lock file is never created here)."""
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except OSError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        finally:
            os.close(fd)  # (a shared lock taken here goes with it)
        return None

    def release(self) -> None:
        """Let the store go (after it is closed). Idempotent."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
