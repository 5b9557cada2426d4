"""The cycle recorder over the store: every step, figure and image of a running cycle is persisted.

A write the store refuses (:mod:`cellctl.cell.store_faults`) is kept and written again in order, before the
cycle's final record. Before the install it also ends the cycle (:class:`WriteRefused`, alarm 1703): the install
marker is written at once or the install does not begin. After the install the cycle goes on and measures its glass.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import time
from collections.abc import Awaitable, Callable
from functools import partial
from pathlib import Path
from typing import Any

from cellctl.cell.events import EventHub
from cellctl.cell.packml import PackMLMachine
from cellctl.cell.store_faults import STORE_FAULTS, KeptWrite, WriteBehind, WriteRefused, as_json
from cellctl.domain import CycleStep
from cellctl.ports import CartesianPose
from cellctl.store import AsyncCellStore

log = logging.getLogger(__name__)


class StoreRecorder:
    """Implements :class:`cellctl.cell.cycle_values.CycleRecorder` for one cycle.

    A step stays open until the next one starts; its figures are merged and written when it
    closes. The install step's begin row is the durable "install started" marker of the store.
    """

    def __init__(
        self,
        store: AsyncCellStore | WriteBehind,
        machine: PackMLMachine,
        events: EventHub,
        cycle_id: int,
        image_dir: Path,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._writes = store if isinstance(store, WriteBehind) else WriteBehind(store, None)  # the cell's, or one of its own
        self._store = self._writes.store
        self._installing = False  # the install marker is written: from here on a refused write never ends the cycle
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
    def installing(self) -> bool:
        """The install marker is written: the glass may be in the opening (its error means something)."""
        return self._installing

    @property
    def open_step(self) -> CycleStep | None:
        """The step running now (None before the first and after the last)."""
        return self._open

    async def step_started(self, step: CycleStep) -> None:
        await self._close(ok=True, error=None, strict=True)
        if step is CycleStep.INSTALL:
            await self._install_marker()
        else:
            call = partial(self._store.begin_step, self.cycle_id, step)
            await self._keep(f"{step.name.lower()} step's start", call, {"begin_step": step.name}, strict=True)
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
        step = self._open if self._open is not None else CycleStep.NONE
        try:
            digest = await asyncio.to_thread(_write, path, png)  # a megabyte to disk and its hash: not on the event loop
        except OSError as err:  # a full disk: before the install the cycle ends; after it the measurement counts more
            what = f"cycle {self.cycle_id}'s image {name} ({path})"
            if not self._installing:
                await self._writes.refused(what, err, self.cycle_id)
                raise WriteRefused(f"{what} could not be saved ({err}): the cycle ends before its install") from err
            log.error("%s could not be saved (%s): the cycle goes on without it", what, err)
            self._figures.setdefault("images_not_saved", []).append(name)
            return
        call = partial(self._store.add_image, self.cycle_id, step, name=name, uri=path.name, sha256=digest, size_bytes=len(png))
        await self._keep(f"image {name}", call, {"add_image": name, "step": step.name, "uri": path.name, "sha256": digest})
        self._events.publish("image", {"cycle_id": self.cycle_id, "name": name})

    async def install_started(self, target: CartesianPose) -> None:
        await self.step_started(CycleStep.INSTALL)
        self._figures["install_target"] = {
            "position_mm": list(target.position_mm),
            "quaternion_wxyz": list(target.quaternion_wxyz),
        }

    async def close_step(self, *, ok: bool, error: str | None = None) -> None:
        """Write the open step's figures and close it (kept, if the store refuses it, until it takes it again)."""
        await self._close(ok=ok, error=error, strict=False)

    async def _close(self, *, ok: bool, error: str | None, strict: bool) -> None:
        if self._open is None:
            return
        step, figures = self._open, self._figures
        self._open, self._figures = None, {}
        figures["time_s"] = spent = self._clock() - self._opened_at
        name = step.name.lower()
        self._step_s[name] = self._step_s.get(name, 0.0) + spent
        # The step's duration on the cell's monotonic clock: a wall-clock step in between changes nothing.
        call = partial(self._store.finish_step, self.cycle_id, step, ok=ok, figures=figures, error=error, duration_s=spent)
        body = {"finish_step": step.name, "ok": ok, "figures": figures, "error": error, "duration_s": spent}
        await self._keep(f"{name} step's end", call, body, strict=strict)

    async def _keep(self, what: str, call: Callable[[], Awaitable[object]], body: dict[str, Any], *, strict: bool = True) -> None:
        """Write one row of the cycle, kept if the store refuses it; before the install (``strict``) that ends the cycle."""
        item = KeptWrite(f"cycle {self.cycle_id}'s {what}", call, as_json({"cycle_id": self.cycle_id, **body}), self.cycle_id)
        if not await self._writes.write(item) and strict and not self._installing:
            raise WriteRefused(f"{item.what} was not written (the store refuses writes: alarm 1703): the cycle ends "
                               "before its install")  # fmt: skip

    async def _install_marker(self) -> None:
        """The install-started marker, written now or never: no install without it (kept writes waiting: none)."""
        what = f"cycle {self.cycle_id}'s install marker"
        if self._writes.kept:
            raise WriteRefused(f"{what} was not written: the store has not taken earlier writes yet (alarm 1703); the "
                               "install did not begin")  # fmt: skip
        try:
            await self._store.begin_step(self.cycle_id, CycleStep.INSTALL)
        except STORE_FAULTS as err:
            await self._writes.refused(what, err, self.cycle_id)
            raise WriteRefused(f"{what} was not written ({type(err).__name__}: {err}): the install did not begin") from err
        self._installing = True
        self._writes.installing = self.cycle_id

    def step_times_s(self) -> dict[str, float]:
        """Seconds on the cell's clock spent in each step so far (a step entered again adds up), in order of first entry."""
        return {name: round(s, 4) for name, s in self._step_s.items()}


def _write(path: Path, data: bytes) -> str:
    """Write ``data`` to ``path``; returns its SHA-256 (hex)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return hashlib.sha256(data).hexdigest()
