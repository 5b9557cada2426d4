"""What a commissioning procedure works with: the devices' ports, the engineer, and its dataset.

A procedure only sees a :class:`JobContext`: the robot, laser and camera behind their ports (the
robot wrapped so that no move exceeds the procedure's reduced speed), ``ask`` to pause for the
engineer, ``progress`` to report, and a :class:`DatasetDraft` it fills as samples arrive. The job
runner writes the draft as a complete dataset when the procedure finishes, or as a partial one
(marked so) when it is cancelled or fails. The draft lives in memory until then: a process killed
outright (SIGKILL, power loss) loses it, and the job is marked interrupted at the next start, to be
run again. The same code runs on
hardware and in the simulated cell; there, a :class:`Witness` adds the twin's truth to the
manifest for the report (it is never read by a computation).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from cellctl.calibration.calibration_set import CalibrationSet
from cellctl.calibration.dataset import Dataset, write_dataset
from cellctl.calibration.recording import software
from cellctl.cell.cancel import to_the_end
from cellctl.cell.cycle_values import CellDevices
from cellctl.commissioning.plans import MotionPlan
from cellctl.commissioning.prompts import Ask
from cellctl.config.calibration_procedure import MotionSettings
from cellctl.config.schema import CellConfig
from cellctl.ports import Frame, Identified

Progress = Callable[[int, int, str], None]


def _quiet(done: int, total: int, message: str) -> None:
    return None


def _no_frame(frame: Frame) -> None:
    return None


def _no_plan(plan: MotionPlan) -> None:
    return None


class Witness(Protocol):
    """The simulated cell's truth about what a dataset measured (None on hardware)."""

    def truth(self, kind: str, facts: dict[str, Any]) -> dict[str, Any] | None:
        """The truth for a dataset of ``kind``; ``facts`` are the procedure's results it may need (e.g. g_Pos_0)."""
        ...


@dataclass
class DatasetDraft:
    """A dataset being collected: its kind, manifest fields and images so far."""

    kind: str
    manifest: dict[str, Any] = field(default_factory=dict)
    images: dict[str, NDArray[np.uint8]] = field(default_factory=dict)

    def write(self, dest: Path, *, partial_reason: str | None = None) -> Dataset:
        """Write it into ``dest``; a partial one says why it ended and cannot be computed from."""
        manifest = dict(self.manifest)
        if partial_reason is not None:
            manifest["partial"] = True
            manifest["ended"] = partial_reason
        return write_dataset(dest, self.kind, manifest, self.images)


def device_identity(device: object) -> dict[str, str]:
    """What a device says about itself (model, serial, address), or its kind when it says nothing."""
    if isinstance(device, Identified):
        return {k: str(v) for k, v in device.identity().items()}
    return {"kind": type(device).__name__}


def describe_source(config: CellConfig, devices: CellDevices) -> dict[str, Any]:
    """Which cell and which devices a dataset came from, for its manifest."""
    return {
        "cell": config.cell_id,
        "mode": config.mode,
        "robot": device_identity(devices.robot),
        "laser": device_identity(devices.laser),
        "camera": device_identity(devices.camera),
        "software": software(),
    }


@dataclass
class JobContext:
    """Everything a procedure may use.

    Attributes:
        job_id: the job's number (in prompts and the dataset manifest).
        config: the cell configuration.
        devices: the three ports; the robot is a :class:`cellctl.cell.robots.ReducedSpeedRobot`.
        calibration: the calibration set in use when the job started (None if there is none).
        motion: speeds and timeouts of the procedure's moves and reads.
        ask: pause for the engineer.
        dest: the folder the dataset goes to.
        plan: the plan shown before the first move.
        witness: the twin's truth (simulated cell only).
        progress: (done, total, message) as the procedure goes.
        on_frame: every frame grabbed (the dashboard's live image).
        on_plan: the plan, when the procedure shows it.
        written: the complete dataset, once written.
        robot_left: where the robot stands while nothing may move it as it is (the glass in the opening) and
            what to do; a job ending meanwhile says it. None when the robot may move on.
    """

    job_id: int
    config: CellConfig
    devices: CellDevices
    calibration: CalibrationSet | None
    motion: MotionSettings
    ask: Ask
    dest: Path
    plan: MotionPlan | None = None
    witness: Witness | None = None
    progress: Progress = _quiet
    on_frame: Callable[[Frame], None] = _no_frame
    on_plan: Callable[[MotionPlan], None] = _no_plan
    draft: DatasetDraft | None = None
    source: dict[str, Any] = field(default_factory=dict)
    written: Dataset | None = None
    robot_left: str | None = None

    @property
    def store_root(self) -> Path | None:
        """The calibration store folder the dataset goes into (``dest`` is ``<store>/datasets/<name>``, as a job's
        is); None when ``dest`` lies elsewhere."""
        return self.dest.parent.parent if self.dest.parent.name == "datasets" else None

    def show_plan(self, plan: MotionPlan) -> None:
        """The plan the robot is about to follow (shown before the first move)."""
        self.plan = plan
        self.on_plan(plan)

    def begin(self, kind: str, **manifest: Any) -> DatasetDraft:
        """Start the dataset this job collects (written partial if the job ends early)."""
        self.draft = DatasetDraft(kind, {"source": self.source, "job_id": self.job_id, **manifest})
        return self.draft

    async def finish(self, facts: dict[str, Any] | None = None) -> Dataset:
        """Write the complete dataset (with the twin's truth, in the simulated cell), off the event loop."""
        assert self.draft is not None, "begin() the dataset first"
        if self.witness is not None:
            truth = self.witness.truth(self.draft.kind, facts or {})
            if truth:
                self.draft.manifest["twin_truth"] = truth
        draft, self.draft = self.draft, None  # taken: a cancel from here on writes no partial copy beside it
        ds, cancelled = await to_the_end(asyncio.to_thread(draft.write, self.dest))
        self.written = ds
        if cancelled:  # the dataset is complete and kept; the job still ends cancelled
            raise asyncio.CancelledError
        return ds
