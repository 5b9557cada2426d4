"""The PLC interface's view of the cell (:class:`cellctl.plc.CellFacade`) over the orchestrator."""

from __future__ import annotations

import asyncio
import contextlib
import logging

from cellctl.cell.alarms import AlarmCode
from cellctl.cell.orchestrator import CellOrchestrator, CycleRefused, summarize
from cellctl.cell.packml import CommandRefused, ModeChangeNotAllowed
from cellctl.cell.tags import PackMLCommand, UnitMode
from cellctl.plc.facade import CellStatus, CommandReply, CycleAcceptance, CycleOutcome
from cellctl.store import CycleRequest, IdempotencyConflict

log = logging.getLogger(__name__)

PLC_SCOPE = "plc"
PLC_ACTOR = "line-plc"


class PlcCellLink:
    """Implements CellFacade: PLC cycle ids are idempotency keys in the store's ``plc`` scope.

    ``recipes`` maps the PLC's recipe number to the recipe name the cell records.
    """

    def __init__(self, orch: CellOrchestrator, recipes: dict[int, str], *, heartbeat_alarm: bool = True) -> None:
        self._orch = orch
        self._recipes = recipes
        self._heartbeat_alarm = heartbeat_alarm
        self._tasks: set[asyncio.Task[object]] = set()

    def status(self) -> CellStatus:
        st = self._orch.machine.status()
        stop = self._orch.alarms.stop_reason
        return CellStatus(
            state=st.state,
            unit_mode=st.mode,
            cycle_step=st.cycle_step,
            stop_reason_id=0 if stop is None else int(stop.code),
            ready_for_cycle=self._orch.ready_for_cycle(),
        )

    async def start_cycle(self, req_id: int, recipe_id: int, part_id: int) -> CycleAcceptance:
        recipe = self._recipes.get(recipe_id)
        if recipe is None:
            return CycleAcceptance(False, int(AlarmCode.TASK_FAILED), f"unknown recipe number {recipe_id}")
        try:
            await self._orch.submit_cycle(
                CycleRequest(recipe, str(part_id), None, source="plc"), scope=PLC_SCOPE, key=str(req_id), actor=PLC_ACTOR
            )
        except CycleRefused as err:
            return CycleAcceptance(False, err.code, err.reason)
        except IdempotencyConflict as err:
            return CycleAcceptance(False, int(AlarmCode.TASK_FAILED), str(err))
        return CycleAcceptance(True)

    async def result_of(self, req_id: int) -> CycleOutcome | None:
        record = await self._orch.store.cycle_for_key(PLC_SCOPE, str(req_id))
        if record is None:
            return None
        s = summarize(record)
        if s is None:
            return None
        recipe_id = next((k for k, v in self._recipes.items() if v == record.request.recipe), 0)
        try:
            part = int(record.request.part_id)
        except ValueError:
            part = 0
        return CycleOutcome(
            req_id=req_id,
            recipe_id=recipe_id,
            part_id=part,
            ok=s.ok,
            error_code=s.error_code,
            dx_mm=s.correction_mm[0],
            dy_mm=s.correction_mm[1],
            dz_mm=s.correction_mm[2],
            drx_rad=s.correction_rad[0],
            dry_rad=s.correction_rad[1],
            drz_rad=s.correction_rad[2],
            cycle_time_s=s.cycle_time_s,
        )

    async def command(self, command: PackMLCommand) -> CommandReply:
        try:
            await self._orch.command(command, actor=PLC_ACTOR, source="plc")
        except CommandRefused:
            return CommandReply.INVALID_IN_STATE
        return CommandReply.ACCEPTED

    async def change_mode(self, mode: UnitMode) -> CommandReply:
        try:
            await self._orch.machine.change_mode(mode, actor=PLC_ACTOR, source="plc")
        except ModeChangeNotAllowed:
            return CommandReply.INVALID_IN_STATE
        return CommandReply.ACCEPTED

    def plc_link_lost(self, silent_for_s: float) -> None:
        self._orch.note_link("plc", "lost", silent_for_s=round(float(silent_for_s), 2))
        if not self._heartbeat_alarm:
            log.warning("PLC heartbeat lost for %.1f s (plc.heartbeat_alarm is off: no alarm)", silent_for_s)
            return
        self._spawn(
            self._orch.alarms.raise_alarm(
                AlarmCode.PLC_HEARTBEAT_LOST, source="plc", detail=f"no heartbeat for {silent_for_s:.1f} s",
                robot_moving=self._orch.robot.moving,
            )  # fmt: skip
        )

    def plc_link_restored(self) -> None:
        self._orch.note_link("plc", "up")
        self._orch.alarms.clear(AlarmCode.PLC_HEARTBEAT_LOST, source="plc")

    def _spawn(self, coro: object) -> None:
        task = asyncio.ensure_future(coro)  # type: ignore[arg-type]
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def close(self) -> None:
        for t in list(self._tasks):
            t.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
