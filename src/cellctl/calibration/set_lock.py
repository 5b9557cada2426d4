"""How writers of one calibration folder keep out of each other's way.

The service's commissioning jobs and an offline ``cellctl calibrate ... --dataset`` may write the same
folder. A commit (read the set in use, number the new version, write it, move the pointer) runs under an
exclusive ``flock`` on ``<folder>/.lock``; a second writer waits a bounded time, then is refused with
:class:`CalibrationStoreBusy`. The kernel drops the lock when its process dies, so none is ever stale.
Files are written to a unique temporary name and fsynced before they take their name; a version file
takes it with ``link`` (never over an existing one), the pointer with ``rename``.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from cellctl.calibration.set_parts import CalibrationSetError
from cellctl.pidlock import LockHeld, take

LOCK_NAME = ".lock"
LOCK_WAIT_S = 10.0  # a commit holds the lock for milliseconds; this long means the other writer is stuck
TEMP_SUFFIX = ".tmp"


class CalibrationStoreBusy(CalibrationSetError):
    """Another process kept the calibration store's lock longer than this writer would wait."""


@contextlib.contextmanager
def store_lock(root: Path, timeout_s: float | None = None) -> Iterator[None]:
    """Hold the exclusive lock of the store in ``root`` (which must exist); wait at most ``timeout_s`` s
    (default :data:`LOCK_WAIT_S`) for it."""
    wait_s = LOCK_WAIT_S if timeout_s is None else timeout_s
    try:
        fd = take(root / LOCK_NAME, wait_s=wait_s)
    except LockHeld as held:
        who = f"pid {held.holder}" if held.holder.isdigit() else "pid unknown"
        raise CalibrationStoreBusy(
            f"the calibration store {root} is in use by another process ({who}) for more than {wait_s:g} s; try again"
        ) from None
    try:
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the flock


def write_file(path: Path, text: str, *, exclusive: bool) -> None:
    """Write ``text`` to ``path`` whole or not at all; ``exclusive``: refuse if ``path`` exists (FileExistsError)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        if exclusive:
            os.link(tmp, path)
            os.unlink(tmp)
        else:
            os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _sync_folder(path.parent)


def remove_stale_temps(root: Path) -> None:
    """Delete temporary files a writer that died left behind (call under the lock: no writer is live then)."""
    for f in root.glob(f".set-*{TEMP_SUFFIX}"):
        f.unlink(missing_ok=True)
    for f in root.glob(f".current.*{TEMP_SUFFIX}"):
        f.unlink(missing_ok=True)


def _sync_folder(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
