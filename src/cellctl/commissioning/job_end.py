"""How a commissioning job's end reads: its state and error from what ended it, and what it leaves behind.

A job ends ``cancelled``, ``refused`` or ``failed`` with an error saying why; the samples it collected
are written as a partial dataset; and where it left the robot somewhere nothing may move it from as
it is (the glass in the car body's opening), the error says so and what to do first.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.set_lock import CalibrationStoreBusy
from cellctl.commissioning.context import JobContext
from cellctl.commissioning.plans import PlanError
from cellctl.commissioning.prompts import PromptCancelled
from cellctl.ports import DeviceError

log = logging.getLogger(__name__)

LATE_CANCEL = "the cancel came while the complete dataset was being written: it was finished and is kept"


def ended_by(err: BaseException, cancel_reason: str | None, job_id: int) -> dict[str, Any]:
    """The record's ``state`` and ``error`` for what ended a job early (``cancel_reason``: a cancel's, if one came)."""
    if isinstance(err, asyncio.CancelledError):
        return {"state": "cancelled", "error": cancel_reason or "cancelled: the service is stopping"}
    if isinstance(err, PromptCancelled):
        return {"state": "cancelled", "error": str(err)}
    if isinstance(err, CalibrationRefused):
        return {"state": "refused", "error": f"{err.reason}: {err.detail}"}
    if isinstance(err, (DeviceError, PlanError, CalibrationStoreBusy)):
        return {"state": "cancelled" if cancel_reason else "failed", "error": cancel_reason or f"{type(err).__name__}: {err}"}
    log.error("commissioning job %d failed", job_id, exc_info=err)  # any bug still ends the job with a record
    return {"state": "failed", "error": f"software fault: {type(err).__name__}: {err}"}


def say_where_the_robot_was_left(fields: dict[str, Any], robot_left: str | None) -> None:
    """Add to the error of a job that did not end ``done`` where it left the robot, when nothing may move it as it is."""
    if robot_left and fields.get("state") != "done":
        fields["error"] = f"{fields.get('error') or fields.get('state', 'ended')}. {robot_left}"


async def keep_what_was_collected(ctx: JobContext, fields: dict[str, Any], job_id: int) -> None:
    """Name the job's dataset in ``fields``: the draft written as a partial dataset if the job ended before it was
    complete, or the complete one when a cancel came while it was written."""
    if ctx.draft is not None:
        reason = fields.get("error") or fields.get("state", "ended early")
        try:
            ds = await asyncio.to_thread(ctx.draft.write, ctx.dest, partial_reason=str(reason))
            fields["dataset"] = str(ds.root)
        except Exception:  # noqa: BLE001 - the record must still be written
            log.exception("job %d: writing the partial dataset failed", job_id)
    elif ctx.written is not None and "dataset" not in fields:
        fields["dataset"] = str(ctx.written.root)
        if fields.get("state") == "cancelled":
            fields["error"] = f"{fields.get('error')} ({LATE_CANCEL})"
