"""Commission the parts of the calibration set that are missing, failed or out of date, in order.

The simulated cell's root runs this at start (``calibration.auto_calibrate_in_sim``), with its
simulated operator answering the prompts: the same jobs, through the same job manager, that an
engineer starts with ``cellctl calibrate ...`` and ``cellctl teach``.
"""

from __future__ import annotations

import logging
from datetime import datetime, timezone

from cellctl.calibration.calibration_set import check_ready
from cellctl.cell.packml import PackMLMachine
from cellctl.cell.tags import PackMLCommand, PackMLState
from cellctl.commissioning.jobs import JOB_STATES_ALLOWED, JobManager
from cellctl.commissioning.procedures import ORDER
from cellctl.store import JobRecord

log = logging.getLogger(__name__)


class CommissioningFailed(RuntimeError):
    """A commissioning job did not end ``done``; the message names it and why."""


def parts_needed(jobs: JobManager) -> list[str]:
    """The parts (in commissioning order) whose calibration is missing, failed, stale or expired."""
    cal = jobs.current_calibration()
    if cal is None:
        return list(ORDER)
    problems = check_ready(cal, datetime.now(timezone.utc))
    return [part for part in ORDER if any(p.startswith(f"{part}:") for p in problems)]


async def commission_missing(
    jobs: JobManager, machine: PackMLMachine, *, actor: str, source: str, job_timeout_s: float = 3600.0
) -> list[JobRecord]:
    """Run the needed procedures one after the other; returns their job records.

    An Aborted cell is cleared first (jobs run in Stopped or Idle). Raises CommissioningFailed
    at the first job that does not end ``done``.
    """
    done: list[JobRecord] = []
    if not parts_needed(jobs):
        return done
    if machine.state is PackMLState.ABORTED:
        await machine.command(PackMLCommand.CLEAR, actor=actor, source=source)
        await machine.wait_for_state(*JOB_STATES_ALLOWED, timeout_s=30.0)
    while needed := parts_needed(jobs):
        part = needed[0]
        log.info("commissioning %s (missing, failed or out of date)", part)
        rec = await jobs.submit(part, {}, actor=actor, source=source)
        rec = await jobs.wait(rec.id, job_timeout_s)
        done.append(rec)
        if rec.state != "done":
            raise CommissioningFailed(f"job {rec.id} ({part}) ended {rec.state}: {rec.error}")
    return done
