"""What a retention pass reports and the figures /status shows of it (no I/O)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from datetime import datetime, timezone
from typing import Any

from cellctl.service.retention_plan import MB


@dataclass
class PassReport:
    """What one retention pass did."""

    images_pruned: int = 0
    images_missing: int = 0
    images_restored: int = 0
    orphans_deleted: int = 0
    cycles_deleted: int = 0
    alarms_deleted: int = 0
    seconds: float = 0.0

    def add(self, other: PassReport) -> None:
        """Count ``other`` in as well (the totals since start are one report summed over the passes)."""
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name) + getattr(other, f.name))


def iso_utc(t: datetime | None) -> str | None:
    return None if t is None else t.astimezone(timezone.utc).isoformat(timespec="seconds")


@dataclass
class Figures:
    """The figures of the last pass and disk check (``status()`` reads them, never a scan)."""

    images_bytes: int | None = None
    images_count: int | None = None
    oldest_image: datetime | None = None
    images_checked: datetime | None = None
    database_bytes: int | None = None
    free_bytes: int | None = None
    free_path: str | None = None
    disk: str = "unknown"
    disk_checked: datetime | None = None
    last_pass: datetime | None = None
    last_error: str | None = None
    images_problem: str | None = None  # the image folder looks unmounted: the image part is skipped
    disk_problem: str | None = None  # a file system the last disk check could not measure
    deferred: bool = False
    extra: dict[str, Any] = field(default_factory=dict)


def clear_at(threshold: float) -> float:
    """A disk alarm clears only this far above its threshold (no flapping around it)."""
    return threshold + max(0.1 * threshold, 50 * MB) if threshold > 0 else 0.0
