"""Commissioning procedures on a twin without the service: for tests and benchmarks.

The same procedure coroutines the service's jobs run (:mod:`cellctl.commissioning`), on the
twin's in-process devices behind the ports, with the simulated operator answering the prompts
and the twin's truth written into the datasets. Only the job bookkeeping (store rows, events,
the PackML interlock) is left out, so many simulated cells can be calibrated quickly.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from cellctl.calibration.calibration_set import CalibrationSet
from cellctl.calibration.dataset import Dataset
from cellctl.cell.cycle import CellDevices
from cellctl.cell.robots import ReducedSpeedRobot
from cellctl.commissioning.context import JobContext, describe_source
from cellctl.commissioning.registry import ALL_PROCEDURES, motion_settings
from cellctl.commissioning.prompts import Answer, PromptDesk
from cellctl.config.schema import CellConfig
from cellctl.sim.cell import SimCell
from cellctl.sim.operator import SimulatedOperator, TwinWitness
from cellctl.sim.rig import SimRig


class TwinCommissioning:
    """A twin (seeded), its devices and its operator, ready to run commissioning procedures.

    Args:
        config: the cell configuration (its ``sim`` section builds the twin).
        seed: overrides ``sim.seed``.
    """

    def __init__(self, config: CellConfig, *, seed: int | None = None) -> None:
        self.config = config
        sim = config.sim.model_copy(update={"operator": config.sim.operator.model_copy(update={"answers": "all", "answer_delay_s": 0.0})})
        self.rig = SimRig(config.sim, seed=seed)
        self.operator = SimulatedOperator(self.rig.cell, sim, self.rig.targets, self.rig.cell.execute)
        self.witness = TwinWitness(self.rig.cell, config.sim, self.operator, self.rig.camera)
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
        await self.operator.close()
        await self.rig.close()
