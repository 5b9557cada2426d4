"""An exclusive ``flock`` on a file that names its holder's pid: one process at a time (a service per store, a
writer per calibration folder). The kernel drops the lock when its process dies, so none is ever stale."""

from __future__ import annotations

import fcntl
import os
import time
from pathlib import Path

POLL_S = 0.02


class LockHeld(Exception):
    """Another process holds the lock; ``holder`` is its pid as it wrote it ("unknown" if it wrote none)."""

    def __init__(self, holder: str) -> None:
        super().__init__(holder)
        self.holder = holder


def take(path: Path, *, wait_s: float = 0.0) -> int:
    """Take the lock on ``path`` (created if missing), waiting at most ``wait_s``; returns the descriptor that
    holds it (closing it lets go). Raises LockHeld."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    deadline = time.monotonic() + max(0.0, wait_s)
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if time.monotonic() >= deadline:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
                os.close(fd)
                raise LockHeld(holder) from None
            time.sleep(POLL_S)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd


def holder(path: Path) -> str | None:
    """The pid of the process holding the lock on ``path`` now (None: nobody; the file is never created here)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
    finally:
        os.close(fd)  # (a shared lock taken here goes with it)
    return None
