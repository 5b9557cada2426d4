"""What the job manager (:mod:`cellctl.commissioning.jobs`) keeps of a running job, and the small rules it applies."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from cellctl.calibration.calibration_set import CalibrationSet, CalibrationStore, damage_text
from cellctl.cell.packml import CYCLE_STATES
from cellctl.commissioning.context import JobContext
from cellctl.commissioning.registry import JobRefused
from cellctl.config.schema import CellConfig
from cellctl.domain import PackMLState
from cellctl.ports import Frame
from cellctl.store import JobRecord


@dataclass
class RunningJob:
    """The running job: its record, task and context, why it is being cancelled, its live image and progress."""

    record: JobRecord
    task: asyncio.Task[None] | None = None
    ctx: JobContext | None = None
    cancel_reason: str | None = None
    frame: Frame | None = None
    frames: int = 0
    started: float = field(default_factory=time.monotonic)  # time.monotonic(), s
    progress: dict[str, Any] = field(default_factory=dict)
    updates: int = 0

    def note_progress(self, done: int, total: int, message: str) -> None:
        """Set ``progress``: steps done of total, the message, the time elapsed and the time left (s, from the plan's pace)."""
        elapsed = time.monotonic() - self.started
        plan = self.ctx.plan if self.ctx is not None else None
        left = None
        if plan is not None and plan.moves_s and done > 0:
            est_done = max(plan.estimated_s - plan.remaining_s(done), 1e-6)
            left = plan.remaining_s(done) * max(elapsed / est_done, 0.0)
        self.progress = {"done": done, "total": total, "message": message, "elapsed_s": elapsed, "time_left_s": left}


def way_to_a_job(state: PackMLState) -> str:
    """What to send to reach Stopped or Idle (a Stop in Execute, Held or Suspended ends the cycle in progress)."""
    if state is PackMLState.ABORTED:
        return "send Clear first"
    return "send Stop first" + ("" if state not in CYCLE_STATES else ", once the cycle in progress has ended: "
                                "Stop ends a running (or held) cycle at once and drops the queued ones")  # fmt: skip


def config_for(config: CellConfig, opts: Mapping[str, Any]) -> CellConfig:
    """The configuration a job runs with: its recipe's, and the hand-eye method it asks for."""
    config = config.for_recipe(opts.get("recipe") or config.default_recipe)
    method = opts.get("method")
    if method is None:
        return config
    proc = config.calibration.procedure
    proc = proc.model_copy(update={"hand_eye": proc.hand_eye.model_copy(update={"method": method})})
    return config.model_copy(update={"calibration": config.calibration.model_copy(update={"procedure": proc})})


def calibration_in_use(store: CalibrationStore) -> CalibrationSet | None:
    """The set in use (None before the first calibration); a damaged one is JobRefused saying how to restore it."""
    try:
        return store.current()
    except (ValueError, OSError) as err:  # CalibrationSetError is a ValueError; alarm 1305 says the same
        try:
            version = store.current_version()
        except (ValueError, OSError):  # the pointer itself is what is damaged (mistyped, empty, unreadable)
            version = None
        raise JobRefused(damage_text(store, err, version), conflict=True) from None
