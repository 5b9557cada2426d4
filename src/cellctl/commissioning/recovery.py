"""At start-up: the jobs a dead process left running, and the calibration-set version each may have stored.

A job stores its new version (note ``"<part>: job <id>"``) before its record says so; a service stopped
in between (power loss, SIGKILL) leaves a record without the version while that version is in the store.
The store knows only job rows and the calibration folder only sets, so the two are joined here.
"""

from __future__ import annotations

import asyncio
import logging

from cellctl.calibration.calibration_set import PART_NAMES, CalibrationStore
from cellctl.store import AsyncCellStore, JobRecord

log = logging.getLogger(__name__)


def job_note_id(note: str) -> int | None:
    """The job id a set version's note names (``"teaching: job 7"`` -> 7), or None for any other note."""
    part, sep, tail = note.rpartition(": job ")
    return int(tail) if sep and part in PART_NAMES and tail.isdigit() else None


def version_stored_by(calibration_store: CalibrationStore, rec: JobRecord) -> int | None:
    """The set version job ``rec`` stored: newer than the one in use when it started, its note naming the job."""
    for version in reversed(calibration_store.versions()):
        if version <= (rec.version_before or 0):
            break
        try:
            note = calibration_store.load(version).note
        except (ValueError, OSError):  # a damaged version was not stored by anyone usable
            continue
        if job_note_id(note) == rec.id:
            return version
    return None


def stored_text(version: int, in_use: int | None) -> str:
    """The interrupted job's reason when its version was stored before the stop."""
    use = "it is the set in use" if in_use == version else f"the set in use now is version {in_use or 'unreadable'}"
    return (f"interrupted after it stored calibration set version {version} ({use}): the service stopped before "
            "the job's record was written; its result is that version (cellctl calibrate status --history)")  # fmt: skip


async def recover_jobs(store: AsyncCellStore, calibration_store: CalibrationStore) -> list[JobRecord]:
    """Mark the jobs a dead process left running interrupted; one that stored its version gets it as version_after."""
    out = []
    for job_id in await store.recover_jobs():
        rec = await store.job(job_id)
        version = await asyncio.to_thread(version_stored_by, calibration_store, rec)
        if version is None:
            log.warning("commissioning job %d was interrupted by a restart; what it had collected was not kept", job_id)
        else:
            in_use = await asyncio.to_thread(_in_use, calibration_store)
            rec = await store.update_job(job_id, version_after=version, error=stored_text(version, in_use))
            log.warning("commissioning job %d was interrupted by a restart after it stored calibration set version %d",
                        job_id, version)  # fmt: skip
        out.append(rec)
    return out


def _in_use(calibration_store: CalibrationStore) -> int | None:
    try:
        return calibration_store.current_version()
    except (ValueError, OSError):
        return None
