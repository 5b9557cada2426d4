"""The OPC UA server's view of the cell (:class:`cellctl.opcua.port.OpcUaCell`) over the orchestrator.

A ``StartCycle`` RequestId is an idempotency key in the store's ``opcua`` scope, as a PLC
``cycle_req_id`` is in the ``plc`` scope: a repeated id answers the cycle it made and starts nothing,
across restarts too. A refusal is not stored: the caller got it as the call's status, and the same id
may be tried again once the cell is ready.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from cellctl.cell.alarms import UnknownAlarm
from cellctl.cell.orchestrator import CellOrchestrator, CycleRefused
from cellctl.cell.outcome import result_message
from cellctl.cell.packml import CommandRefused, ModeChangeNotAllowed, TakenCommand
from cellctl.domain import Alarm, PackMLCommand, UnitMode
from cellctl.opcua.port import Refused, Snapshot
from cellctl.store import CycleRecord, CycleRequest, CycleState, IdempotencyConflict

log = logging.getLogger(__name__)

OPCUA_SCOPE = "opcua"
FINISHED = (CycleState.DONE, CycleState.FAILED, CycleState.INTERRUPTED)


class OpcUaCellLink:
    """Implements OpcUaCell; every change is audited with the OPC UA user's name by the orchestrator."""

    def __init__(self, orch: CellOrchestrator, cell_id: str, recipes: tuple[str, ...]) -> None:
        self._orch = orch
        self.cell_id = cell_id
        self.recipes = recipes

    def snapshot(self) -> Snapshot:
        st = self._orch.machine.status()
        return Snapshot(st.state, st.mode, st.cycle_step, self._orch.ready_for_cycle(), self._orch.alarms.stop_reason)

    def subscribe(self) -> asyncio.Queue[Any]:
        return self._orch.events.subscribe()

    def unsubscribe(self, queue: asyncio.Queue[Any]) -> None:
        self._orch.events.unsubscribe(queue)

    async def command(self, command: PackMLCommand, *, actor: str) -> None:
        try:
            ev = await self._orch.command(command, actor=actor, source="opcua")
        except CommandRefused as err:
            raise Refused("BadInvalidState", str(err)) from None
        if isinstance(ev, TakenCommand):  # e.g. a Stop in Stopped that cancelled a commissioning job: Good
            log.info("OPC UA command %s by %s: %s", command.name, actor, ev.effect)

    async def change_mode(self, mode: UnitMode, *, actor: str) -> None:
        try:
            await self._orch.machine.change_mode(mode, actor=actor, source="opcua")
        except ModeChangeNotAllowed as err:
            raise Refused("BadInvalidState", str(err)) from None

    async def start_cycle(self, recipe: str, part_id: str, car_id: str | None, request_id: str, *, actor: str) -> int:
        # A repeat of the same request answers with its cycle in any state (the orchestrator looks the key up
        # before the state); the same RequestId with another request is refused (IdempotencyConflict below).
        if recipe not in self.recipes:
            raise Refused("BadInvalidArgument", f"Recipe '{recipe}' is not a recipe of this cell (valid: "
                                                f"{', '.join(self.recipes)}; [[process.recipes]] in the config)")  # fmt: skip
        try:
            request = CycleRequest(recipe, part_id, car_id or None, source="opcua")
        except ValueError as err:
            raise Refused("BadInvalidArgument", str(err)) from None
        try:
            sub = await self._orch.submit_cycle(request, scope=OPCUA_SCOPE, key=request_id, actor=actor)
        except CycleRefused as err:
            raise Refused("BadInvalidState", err.reason) from None
        except IdempotencyConflict as err:
            raise Refused("BadInvalidArgument", f"RequestId '{request_id}': {err}") from None
        return sub.cycle.id

    async def result_for_request(self, request_id: str) -> tuple[bool, dict[str, Any] | None]:
        record = await self._orch.store.cycle_for_key(OPCUA_SCOPE, request_id)
        if record is None:
            return False, None
        return True, self._message(record)

    async def result_of_cycle(self, cycle_id: int) -> dict[str, Any] | None:
        return self._message(await self._orch.store.cycle(cycle_id))

    async def last_result(self) -> dict[str, Any] | None:
        for record in await self._orch.store.cycles(limit=20):
            if record.state in FINISHED:
                return self._message(await self._orch.store.cycle(record.id))
        return None

    def alarms(self) -> list[Alarm]:
        return self._orch.alarms.current()

    def alarm(self, uid: str) -> Alarm | None:
        try:
            return self._orch.alarms.get(uid)
        except UnknownAlarm:
            return None

    async def acknowledge(self, uid: str, *, actor: str, comment: str) -> Alarm:
        try:
            alarm = self._orch.alarms.acknowledge(uid, by=actor)
        except UnknownAlarm as err:
            raise KeyError(uid) from err
        await self._orch.store.append_audit(
            actor=actor, source="opcua", action="alarm.acknowledge",
            params={"uid": uid, "code": int(alarm.code), "comment": comment}, cycle_id=alarm.cycle_id,
        )  # fmt: skip
        return alarm

    @staticmethod
    def _message(record: CycleRecord) -> dict[str, Any] | None:
        msg = result_message(record)
        if msg is not None:
            msg["request_id"] = record.idempotency_key
        return msg
