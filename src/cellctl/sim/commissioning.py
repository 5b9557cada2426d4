"""Commissioning procedures on a twin without the service, for tests and benchmarks.

The service's own procedure coroutines (:mod:`cellctl.commissioning`) on a :class:`SimRig`'s
devices, its operator answering every prompt at once; only the job bookkeeping (store rows,
events, the PackML interlock) is left out, so many twins can be calibrated quickly.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from cellctl.calibration.calibration_set import CalibrationSet
from cellctl.calibration.dataset import Dataset
from cellctl.cell.cycle_values import CellDevices
from cellctl.cell.robots import ReducedSpeedRobot
from cellctl.commissioning.context import JobContext, describe_source
from cellctl.commissioning.prompts import Answer, PromptDesk
from cellctl.commissioning.registry import ALL_PROCEDURES, motion_settings
from cellctl.config.schema import CellConfig
from cellctl.sim.cell import SimCell
from cellctl.sim.rig import SimRig, recipe_twins


class TwinCommissioning:
    """A seeded :class:`SimRig` with its operator on a prompt desk of its own, ready to run procedures.

    Args:
        config: the cell configuration (its ``sim`` section builds the twin).
        seed: overrides ``sim.seed``.
    """

    def __init__(self, config: CellConfig, *, seed: int | None = None) -> None:
        self.config = config
        self.rig = SimRig(config.sim, seed=seed, recipes=recipe_twins(config))
        self.operator, self.witness = self.rig.add_operator(answer_everything=True)
        self.desk = PromptDesk(lambda kind, data: None)
        self.operator.attach(self.desk.watch, self._answer)
        self.prompts: list[str] = []

    @property
    def cell(self) -> SimCell:
        """The twin (truth, physics)."""
        return self.rig.cell

    async def _answer(self, job_id: int, prompt_id: int, answer: Answer) -> None:
        prompt = self.desk.answer(prompt_id, answer)
        self.prompts.append(prompt.kind.value)

    def context(self, cal: CalibrationSet | None, dest: Path) -> JobContext:
        """A job's context on the rig's devices, the robot at the reduced speed of commissioning."""
        motion = motion_settings(self.config)
        r = self.rig
        devices = CellDevices(r.laser, r.camera, ReducedSpeedRobot(r.robot, motion.speed_mm_s, motion.speed_deg_s))
        return JobContext(
            job_id=0, config=self.config, devices=devices, calibration=cal, motion=motion, ask=self.desk.asker(0),
            dest=Path(dest), witness=self.witness, source=describe_source(self.config, devices),
        )  # fmt: skip

    async def collect(self, procedure: str, cal: CalibrationSet | None, dest: Path, **options: Any) -> Dataset:
        """Run ``procedure``'s collection (as a job would) and return its dataset."""
        return await ALL_PROCEDURES[procedure].collect(self.context(cal, dest), **options)

    async def close(self) -> None:
        await self.rig.close()
