"""The disk check's measurement: the free space of each file system holding the database or the images.

A file system that does not answer (``disk_usage`` raising: an I/O error, a stale NFS handle) is
named with its cause in :attr:`DiskReading.failed`, never skipped: the disk-space alarms cannot
guard it, so the retention task reports it in /status.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class DiskReading:
    """The least free space of the file systems measured (None: none answered) and those that did not."""

    free: int | None
    where: str | None
    failed: tuple[str, ...] = ()  # "<path> (<what>): <error>" for each file system that could not be measured

    def unread(self) -> str:
        """The file systems not measured, each with its cause, and the fix."""
        return (f"cannot read the free space of {'; of '.join(self.failed)}: check that the file system is "
                "mounted and answers (the disk-space alarms cannot guard it until then)")

    def problem(self) -> str | None:
        """What /status says of a check that measured some file systems but not all (None: all were)."""
        return None if not self.failed else f"disk check: {self.unread()}; the free figure is of {self.where} alone"


def _existing(p: Path) -> Path:
    """``p`` or its nearest existing parent (a folder not made yet lives on its parent's file system)."""
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def read_free(paths: Sequence[tuple[str, Path]], disk_usage: Callable[[Path], Any]) -> DiskReading:
    """Measure each (what, path) once per file system; a failure is kept with its cause."""
    seen: dict[int, tuple[int, str]] = {}
    tried: set[int] = set()
    failed: list[str] = []
    for what, path in paths:
        q = _existing(path)
        try:
            dev = q.stat().st_dev
            if dev in tried:
                continue
            tried.add(dev)
            seen[dev] = (int(disk_usage(q).free), str(q))
        except OSError as err:
            failed.append(f"{q} ({what}): {type(err).__name__}: {err}")
    if not seen:
        return DiskReading(None, None, tuple(failed))
    free, where = min(seen.values())
    return DiskReading(free, where, tuple(failed))
