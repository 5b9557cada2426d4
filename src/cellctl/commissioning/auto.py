"""Commission the parts of the calibration set that are missing, failed or out of date, in order;
then teach every other recipe whose own teaching or nine-point map is missing, failed or out of date.

The simulated cell's root runs this at start (``calibration.auto_calibrate_in_sim``), with its
simulated operator answering the prompts: the same jobs, through the same job manager, that an
engineer starts with ``cellctl calibrate ...`` and ``cellctl teach``.
"""

from __future__ import annotations

import logging
from datetime import datetime, timezone
from typing import NamedTuple

from cellctl.calibration.calibration_set import RECIPE_PART_NAMES
from cellctl.calibration.readiness import check_ready
from cellctl.cell.packml import PackMLMachine
from cellctl.commissioning.jobs import JOB_STATES_ALLOWED, JobManager
from cellctl.commissioning.procedures import ORDER
from cellctl.commissioning.registry import JobRefused
from cellctl.domain import PackMLCommand, PackMLState
from cellctl.store import JobRecord

log = logging.getLogger(__name__)


class CommissioningFailed(RuntimeError):
    """A commissioning job did not end ``done``; the message names it and why."""


class Needed(NamedTuple):
    """A part to commission: the procedure, and for a recipe's own part (not the first's) the recipe."""

    part: str
    recipe: str | None = None

    def __str__(self) -> str:
        return self.part if self.recipe is None else f"{self.part} --recipe {self.recipe}"


def parts_needed(jobs: JobManager) -> list[Needed]:
    """The parts (in commissioning order) whose calibration is missing, failed, stale or expired;
    then each further recipe's own."""
    cal = jobs.current_calibration()
    if cal is None:
        return [Needed(part) for part in ORDER]
    now, first = datetime.now(timezone.utc), jobs.config.default_recipe
    problems = check_ready(cal, now, first_recipe=first, config=jobs.config)
    about = {line.partition(": ")[0].split(" of recipe ")[0] for line in problems}  # "teaching" or "teaching of recipe X"
    needed = [Needed(part) for part in ORDER if part in about]
    if needed:
        return needed
    for recipe in jobs.config.process.recipes[1:]:
        own = check_ready(cal, now, recipe=recipe.name, first_recipe=first, config=jobs.config)
        needed += [Needed(part, recipe.name) for part in ORDER
                   if part in RECIPE_PART_NAMES and any(p.startswith(f"{part} of recipe {recipe.name}:") for p in own)]  # fmt: skip
    return needed


async def commission_missing(
    jobs: JobManager, machine: PackMLMachine, *, actor: str, source: str, job_timeout_s: float = 3600.0
) -> list[JobRecord]:
    """Run the needed procedures one after the other; returns their job records.

    An Aborted cell is cleared first (jobs run in Stopped or Idle). A job still running after
    ``job_timeout_s`` is cancelled as an operator's cancel would. Raises CommissioningFailed at the
    first job that does not end ``done``.
    """
    done: list[JobRecord] = []
    if not parts_needed(jobs):
        return done
    if machine.state is PackMLState.ABORTED:
        await machine.command(PackMLCommand.CLEAR, actor=actor, source=source)
        await machine.wait_for_state(*JOB_STATES_ALLOWED, timeout_s=30.0)
    while needed := parts_needed(jobs):
        nxt = needed[0]
        log.info("commissioning %s (missing, failed or out of date)", nxt)
        rec = await jobs.submit(nxt.part, {} if nxt.recipe is None else {"recipe": nxt.recipe}, actor=actor, source=source)
        rec = await jobs.wait(rec.id, job_timeout_s)
        if not rec.finished:
            rec = await _cancel_overdue(jobs, rec, job_timeout_s, actor=actor, source=source)
        done.append(rec)
        if rec.state != "done":
            raise CommissioningFailed(f"job {rec.id} ({nxt}) ended {rec.state}: {rec.error}")
    return done


async def _cancel_overdue(jobs: JobManager, rec: JobRecord, timeout_s: float, *, actor: str, source: str) -> JobRecord:
    """Cancel a job that outlived ``timeout_s`` (its prompt closes, the robot stops, Start is free again)."""
    reason = (f"no end within {timeout_s:g} s (job_timeout_s of cellctl.commissioning.auto.commission_missing): "
              "cancelled; answer its prompts sooner or give a longer job_timeout_s")  # fmt: skip
    log.warning("commissioning job %d (%s): %s", rec.id, rec.procedure, reason)
    try:
        return await jobs.cancel(rec.id, actor=actor, source=source, reason=reason)
    except JobRefused:  # it ended between the wait and the cancel
        return await jobs.job(rec.id)
