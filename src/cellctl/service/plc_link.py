"""The PLC interface's view of the cell (:class:`cellctl.plc.CellFacade`) over the orchestrator.

A PLC ``cycle_req_id`` is an idempotency key in the store's ``plc`` scope: an accepted request is
the cycle made under that key, its request keeping the PLC's ``recipe_id`` (the result's ``result_recipe_id``, and
what a repeat is matched against, whatever ids the recipes have since); a refused one is stored under it as a
finished request whose response is the refusal (the store's ``claim_key`` / ``complete_key``), so a repeated id
republishes the refusal, across restarts too, and can never start a cycle later.

``robot_clear`` comes from a poller: while no cycle runs or waits and the last cycle ended done, it reads the
robot's reported flange pose a few times a second and measures it against that cycle's fitted wall plane
(its record's ``wall_plane_B``); any cycle running voids the reading (:class:`cellctl.plc.clearance.ClearanceWatch`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import astuple

from cellctl.cell.orchestrator import CellOrchestrator, CycleRefused
from cellctl.cell.outcome import summarize
from cellctl.cell.packml import CommandNotAllowed, CommandRefused, ModeChangeNotAllowed, TakenCommand
from cellctl.domain import AlarmCode, CycleStep, PackMLCommand, UnitMode
from cellctl.plc.clearance import ClearanceWatch, FittedWall, flange_to_wall_mm
from cellctl.plc.facade import (
    CellStatus,
    CommandReply,
    CycleAcceptance,
    CycleOutcome,
    PlcErrorCode,
)
from cellctl.ports import DeviceError
from cellctl.store import CycleRecord, CycleRequest, CycleState, IdempotencyConflict, IdempotencyInFlight

log = logging.getLogger(__name__)

PLC_SCOPE = "plc"
PLC_ACTOR = "line-plc"
REFUSED_REQUEST = {"kind": "refused PLC cycle request"}
"""What a refused request's key is claimed with; its stored response holds the refusal."""
CLEAR_POLL_S = 0.2
"""How often the robot's pose is read for ``robot_clear`` while no cycle runs (s)."""
CLEAR_MAX_AGE_S = 1.0
"""A pose reading older than this no longer makes ``robot_clear`` 1 (s): the robot link may be down."""
_WAITING = (CycleState.QUEUED, CycleState.RUNNING)


class PlcCellLink:
    """Implements CellFacade: PLC cycle ids are idempotency keys in the store's ``plc`` scope.

    ``recipes`` maps the PLC's recipe number to the recipe name the cell records.
    """

    def __init__(self, orch: CellOrchestrator, recipes: dict[int, str], *, heartbeat_alarm: bool = True) -> None:
        self._orch = orch
        self._recipes = recipes
        self._heartbeat_alarm = heartbeat_alarm
        self._tasks: set[asyncio.Task[object]] = set()
        self._clearance: ClearanceWatch | None = None  # with its poller, from the first status() in the event loop
        self._clearance_failing = False

    def status(self) -> CellStatus:
        st = self._orch.machine.status()
        stop = self._orch.alarms.stop_reason
        interlock = self._orch.alarms.interlocking()
        return CellStatus(
            state=st.state,
            unit_mode=st.mode,
            cycle_step=st.cycle_step,
            stop_reason_id=0 if stop is None else int(stop.code),
            interlock_alarm_id=int(interlock[0].code) if interlock else 0,
            ready_for_cycle=self._orch.ready_for_cycle(),
            robot_clear=self._robot_clear(),
        )

    # -- robot_clear --------------------------------------------------------------------------

    def _cycle_running(self) -> bool:
        return self._orch.machine.cycle_step is not CycleStep.NONE or self._orch.robot.moving

    def _robot_clear(self) -> bool:
        """The poller's latest verdict, unless a cycle runs now (read every scan: cheap, never blocks)."""
        if self._clearance is None:
            try:
                asyncio.get_running_loop()
            except RuntimeError:  # no event loop: no poller, never clear
                return False
            self._clearance = ClearanceWatch(self._orch.config.plc.clear_distance_mm, CLEAR_MAX_AGE_S)
            self._spawn(self._watch_clearance(self._clearance))
        if self._cycle_running():
            self._clearance.cycle_running()
            return False
        return self._clearance.clear(time.monotonic())

    async def _watch_clearance(self, watch: ClearanceWatch) -> None:
        while True:
            await asyncio.sleep(CLEAR_POLL_S)
            try:
                await self._read_clearance(watch)
            except Exception:  # noqa: BLE001 - robot_clear stays 0; the poller keeps going
                if not self._clearance_failing:
                    log.exception("robot_clear: reading the robot's pose against the wall failed; it stays 0")
                self._clearance_failing = True
            else:
                self._clearance_failing = False

    async def _read_clearance(self, watch: ClearanceWatch) -> None:
        """One reading: the robot's reported flange against the last done cycle's wall (None: not known)."""
        if self._cycle_running():
            watch.cycle_running()
            return
        token = watch.begin()
        wall = await self._last_wall()
        distance = None
        if wall is not None:
            try:
                pose = await self._orch.robot.read_pose(timeout_s=self._orch.config.process.motion.read_timeout_s)
            except DeviceError as err:
                log.debug("robot_clear: no robot pose (%s)", err)
            else:
                distance = flange_to_wall_mm(pose.position_mm, wall)
        if self._cycle_running():
            watch.cycle_running()
            return
        watch.settle(token, time.monotonic(), distance)

    async def _last_wall(self) -> FittedWall | None:
        """The wall plane of the last cycle that ran, if it ended done; None while one runs or waits, and after a
        cycle that failed, stopped or was interrupted (its car body's wall is not known: maybe a glass half in)."""
        for record in await self._orch.store.cycles(limit=20):
            if record.state in _WAITING:
                return None
            if record.started_at is None:  # ended before it began (dropped from the queue): the robot never moved
                continue
            return _wall_of(record)
        return None

    async def start_cycle(self, req_id: int, recipe_id: int, part_id: int, car_body_id: int = 0) -> CycleAcceptance:
        key = str(req_id)  # a repeat of the same request is accepted, nothing new starts; another request: id_in_use
        recipe = self._recipes.get(recipe_id)
        if recipe is None:
            valid = ", ".join(f"{n} ({name})" for n, name in sorted(self._recipes.items()))
            return await self._refuse(req_id, recipe_id, part_id, car_body_id, PlcErrorCode.UNKNOWN_RECIPE,
                                      f"recipe_id {recipe_id} is not a recipe of this cell (valid: {valid}; "
                                      "[[process.recipes]] in the config)")
        try:
            await self._orch.submit_cycle(
                CycleRequest(recipe, str(part_id), str(car_body_id) if car_body_id else None, source="plc",
                             plc_recipe_id=recipe_id),
                scope=PLC_SCOPE, key=key, actor=PLC_ACTOR,
            )
        except CycleRefused as err:  # the cell does not take a cycle now (not in Execute), or not of this recipe
            code = PlcErrorCode.RECIPE_NOT_TAUGHT if err.code == AlarmCode.RECIPE_NOT_TAUGHT else PlcErrorCode.NOT_READY
            return await self._refuse(req_id, recipe_id, part_id, car_body_id, code, err.reason)
        except IdempotencyConflict as err:  # the key is taken by something this request cannot match
            log.warning("PLC cycle request %d: %s", req_id, err)
            return CycleAcceptance(False, int(PlcErrorCode.ID_IN_USE), str(err))
        return CycleAcceptance(True)

    async def _refuse(self, req_id: int, recipe_id: int, part_id: int, car_body_id: int, code: PlcErrorCode,
                      reason: str) -> CycleAcceptance:
        """Store the refusal as the id's result (so a repeat republishes it), then answer it."""
        store, key = self._orch.store, str(req_id)
        try:
            if await store.claim_key(PLC_SCOPE, key, REFUSED_REQUEST) is None:
                response = {"error_code": int(code), "reason": reason, "recipe_id": recipe_id, "part_id": part_id,
                            "car_body_id": car_body_id}
                await store.complete_key(PLC_SCOPE, key, response)
        except (IdempotencyConflict, IdempotencyInFlight) as err:  # taken meanwhile: answer, store nothing
            log.warning("PLC cycle request %d: its refusal could not be stored (%s)", req_id, err)
        return CycleAcceptance(False, int(code), reason)

    async def _stored_refusal(self, req_id: int) -> CycleOutcome | None:
        """The refusal stored under ``req_id``, or None (the id is new: nothing is left behind)."""
        store, key = self._orch.store, str(req_id)
        try:
            stored = await store.claim_key(PLC_SCOPE, key, REFUSED_REQUEST)
        except (IdempotencyConflict, IdempotencyInFlight):
            return None  # the key is a cycle's or in flight: not a refusal
        if stored is None:
            await store.release_key(PLC_SCOPE, key)  # only looked: leave the id free
            return None
        r = stored.response
        return CycleOutcome(
            req_id=req_id, recipe_id=int(r["recipe_id"]), part_id=int(r["part_id"]), ok=False,
            car_body_id=int(r.get("car_body_id", 0)),
            error_code=int(r["error_code"]), dx_mm=0.0, dy_mm=0.0, dz_mm=0.0, drx_rad=0.0, dry_rad=0.0, drz_rad=0.0,
            cycle_time_s=0.0,
        )  # fmt: skip

    async def result_of(self, req_id: int) -> CycleOutcome | None:
        record = await self._orch.store.cycle_for_key(PLC_SCOPE, str(req_id))
        if record is None:
            return await self._stored_refusal(req_id)
        s = summarize(record)
        if s is None:
            return None
        return CycleOutcome(
            req_id=req_id,
            recipe_id=self._recipe_id_of(record.request),
            part_id=_uint32_of(record.request.part_id),
            car_body_id=_uint32_of(record.request.car_id),
            install_started=record.install_started,
            ok=s.ok,
            error_code=s.error_code,
            dx_mm=s.correction_mm[0],
            dy_mm=s.correction_mm[1],
            dz_mm=s.correction_mm[2],
            drx_rad=s.correction_rad[0],
            dry_rad=s.correction_rad[1],
            drz_rad=s.correction_rad[2],
            cycle_time_s=s.cycle_time_s,
            measured=None if s.measured is None else tuple(astuple(s.measured)),  # type: ignore[arg-type]
            measured_ok=None if s.measured is None else s.ok,
        )

    def _recipe_id_of(self, request: CycleRequest) -> int:
        """The recipe_id the PLC requested the cycle with, kept with it; for a record from before it was kept, the
        recipe name's id in today's ``[[process.recipes]]`` (0: no recipe of that name)."""
        if request.plc_recipe_id is not None:
            return request.plc_recipe_id
        return next((k for k, v in self._recipes.items() if v == request.recipe), 0)

    async def command(self, command: PackMLCommand) -> CommandReply:
        """1 (invalid in state) when the state model has no such edge, 5 (blocked) when an interlock holds it back."""
        try:
            ev = await self._orch.command(command, actor=PLC_ACTOR, source="plc")
        except CommandRefused as err:
            reply = CommandReply.INVALID_IN_STATE if isinstance(err, CommandNotAllowed) else CommandReply.BLOCKED
            log.warning("PLC command %s refused (cmd_result %d %s): %s", command.name, reply, reply.name, err)
            return reply
        if isinstance(ev, TakenCommand):  # e.g. a Stop in Stopped that cancelled a commissioning job: accepted
            log.info("PLC command %s: %s", command.name, ev.effect)
        return CommandReply.ACCEPTED

    async def change_mode(self, mode: UnitMode) -> CommandReply:
        try:
            await self._orch.machine.change_mode(mode, actor=PLC_ACTOR, source="plc")
        except ModeChangeNotAllowed as err:
            log.warning("PLC unit mode %s refused (unit_mode_result %d): %s", mode.name,
                        CommandReply.INVALID_IN_STATE, err)
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


def _uint32_of(text: str | None) -> int:
    """A record's part or car id as the PLC's uint32 (0 when it is none, or not a number the register holds)."""
    if text is None or not text.isdecimal():
        return 0
    n = int(text)
    return n if n <= 0xFFFF_FFFF else 0


def _wall_of(record: CycleRecord) -> FittedWall | None:
    """The wall plane a done cycle's record keeps; None for any other ending (the install may have stopped half-way)."""
    if record.state is not CycleState.DONE:
        return None
    return FittedWall.from_record((record.result or {}).get("wall_plane_B"))
