"""The cycle recorder over the store: every step, figure and image of a running cycle is persisted."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from cellctl.cell.events import EventHub
from cellctl.cell.packml import PackMLMachine
from cellctl.cell.tags import CycleStep
from cellctl.ports import CartesianPose
from cellctl.store import AsyncCellStore


class StoreRecorder:
    """Implements :class:`cellctl.cell.cycle.CycleRecorder` for one cycle.

    A step stays open until the next one starts; its figures are merged and written when it
    closes. The install step's begin row is the durable "install started" marker of the store.
    """

    def __init__(
        self, store: AsyncCellStore, machine: PackMLMachine, events: EventHub, cycle_id: int, image_dir: Path
    ) -> None:
        self._store = store
        self._machine = machine
        self._events = events
        self.cycle_id = cycle_id
        self._image_dir = image_dir
        self._open: CycleStep | None = None
        self._figures: dict[str, Any] = {}

    @property
    def open_step(self) -> CycleStep | None:
        """The step running now (None before the first and after the last)."""
        return self._open

    async def step_started(self, step: CycleStep) -> None:
        await self.close_step(ok=True)
        await self._store.begin_step(self.cycle_id, step)
        self._open, self._figures = step, {}
        await self._machine.set_cycle_step(step)
        self._events.publish("step", {"cycle_id": self.cycle_id, "step": step.name.lower()})

    async def step_figures(self, step: CycleStep, figures: dict[str, Any]) -> None:
        if step is not self._open:
            raise RuntimeError(f"figures for {step.name} while {self._open} is the open step")
        self._figures.update(figures)

    async def image(self, name: str, png: bytes) -> None:
        path = self._image_dir / f"cycle-{self.cycle_id}-{name}.png"
        await asyncio.to_thread(_write, path, png)  # a megabyte to disk: not on the event loop
        step = self._open if self._open is not None else CycleStep.NONE
        await self._store.add_image(self.cycle_id, step, name=name, uri=path.name)
        self._events.publish("image", {"cycle_id": self.cycle_id, "name": name})

    async def install_started(self, target: CartesianPose) -> None:
        await self.step_started(CycleStep.INSTALL)
        self._figures["install_target"] = {
            "position_mm": list(target.position_mm),
            "quaternion_wxyz": list(target.quaternion_wxyz),
        }

    async def close_step(self, *, ok: bool, error: str | None = None) -> None:
        """Write the open step's figures and close it."""
        if self._open is None:
            return
        step, figures = self._open, self._figures
        self._open, self._figures = None, {}
        await self._store.finish_step(self.cycle_id, step, ok=ok, figures=figures, error=error)


def _write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
