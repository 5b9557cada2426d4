"""The cycle recorder over the store: every step, figure and image of a running cycle is persisted."""

from __future__ import annotations

import asyncio
import hashlib
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cellctl.cell.events import EventHub
from cellctl.cell.packml import PackMLMachine
from cellctl.domain import CycleStep
from cellctl.ports import CartesianPose
from cellctl.store import AsyncCellStore


class StoreRecorder:
    """Implements :class:`cellctl.cell.cycle.CycleRecorder` for one cycle.

    A step stays open until the next one starts; its figures are merged and written when it
    closes. The install step's begin row is the durable "install started" marker of the store.
    """

    def __init__(
        self,
        store: AsyncCellStore,
        machine: PackMLMachine,
        events: EventHub,
        cycle_id: int,
        image_dir: Path,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._store = store
        self._machine = machine
        self._events = events
        self.cycle_id = cycle_id
        self._image_dir = image_dir
        self._clock = clock
        self._open: CycleStep | None = None
        self._opened_at = 0.0
        self._figures: dict[str, Any] = {}
        self._step_s: dict[str, float] = {}

    @property
    def open_step(self) -> CycleStep | None:
        """The step running now (None before the first and after the last)."""
        return self._open

    async def step_started(self, step: CycleStep) -> None:
        await self.close_step(ok=True)
        await self._store.begin_step(self.cycle_id, step)
        self._open, self._figures, self._opened_at = step, {}, self._clock()
        await self._machine.set_cycle_step(step)
        self._events.publish("step", {"cycle_id": self.cycle_id, "step": step.name.lower()})

    async def step_figures(self, step: CycleStep, figures: dict[str, Any]) -> None:
        if step is not self._open:
            raise RuntimeError(f"figures for {step.name} while {self._open} is the open step")
        self._figures.update(figures)

    async def image(self, name: str, png: bytes) -> None:
        """Write the PNG to the image folder and reference it with its SHA-256 and size (traceability)."""
        path = self._image_dir / f"cycle-{self.cycle_id}-{name}.png"
        digest = await asyncio.to_thread(_write, path, png)  # a megabyte to disk and its hash: not on the event loop
        step = self._open if self._open is not None else CycleStep.NONE
        await self._store.add_image(self.cycle_id, step, name=name, uri=path.name, sha256=digest, size_bytes=len(png))
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
        figures["time_s"] = spent = self._clock() - self._opened_at
        name = step.name.lower()
        self._step_s[name] = self._step_s.get(name, 0.0) + spent
        # The step's duration on the cell's monotonic clock: a wall-clock step in between changes nothing.
        await self._store.finish_step(self.cycle_id, step, ok=ok, figures=figures, error=error, duration_s=spent)

    def step_times_s(self) -> dict[str, float]:
        """Seconds on the cell's clock spent in each step so far (a step entered again adds up), in order of first entry."""
        return {name: round(s, 4) for name, s in self._step_s.items()}


def _write(path: Path, data: bytes) -> str:
    """Write ``data`` to ``path``; returns its SHA-256 (hex)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return hashlib.sha256(data).hexdigest()
