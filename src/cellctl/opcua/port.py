"""What the OPC UA server needs from the cell; the service implements it over the orchestrator
(:mod:`cellctl.service.opcua_link`), as it implements the PLC's :class:`cellctl.plc.CellFacade`."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import Any, Protocol

from cellctl.domain import Alarm, CycleStep, PackMLCommand, PackMLState, UnitMode


@dataclass(frozen=True)
class Snapshot:
    """The cell now, for the status nodes."""

    state: PackMLState
    mode: UnitMode
    step: CycleStep
    ready_for_cycle: bool
    stop_reason: Alarm | None


class Refused(Exception):
    """A command or a cycle request the cell does not take now; ``status`` names the OPC UA status code."""

    def __init__(self, status: str, reason: str) -> None:
        super().__init__(reason)
        self.status = status  # an asyncua StatusCodes name, e.g. "BadInvalidState"
        self.reason = reason


class OpcUaCell(Protocol):
    """The cell as the OPC UA server sees it. Every method returns promptly; a cycle runs in the cell's own task."""

    cell_id: str
    recipes: tuple[str, ...]

    def snapshot(self) -> Snapshot: ...

    def subscribe(self) -> asyncio.Queue[Any]:
        """A queue of the cell's events (objects with ``kind`` and ``data``: state, alarm, cycle)."""
        ...

    def unsubscribe(self, queue: asyncio.Queue[Any]) -> None: ...

    async def command(self, command: PackMLCommand, *, actor: str) -> None:
        """Issue a PackML command; raises :class:`Refused` when the state model forbids it."""
        ...

    async def change_mode(self, mode: UnitMode, *, actor: str) -> None: ...

    async def start_cycle(self, recipe: str, part_id: str, car_id: str | None, request_id: str, *, actor: str) -> int:
        """The cycle id for ``request_id`` (the same for a repeated id, nothing new starts); raises :class:`Refused`."""
        ...

    async def result_for_request(self, request_id: str) -> tuple[bool, dict[str, Any] | None]:
        """(known, result): whether a cycle exists for the id, and its result message once finished."""
        ...

    async def result_of_cycle(self, cycle_id: int) -> dict[str, Any] | None:
        """A finished cycle's result message (:func:`cellctl.cell.outcome.result_message`) with its ``request_id``."""
        ...

    async def last_result(self) -> dict[str, Any] | None: ...

    def alarms(self) -> list[Alarm]:
        """The current alarms (active or not yet acknowledged)."""
        ...

    def alarm(self, uid: str) -> Alarm | None:
        """One alarm occurrence as it is now (also a finished one still in memory), None if unknown."""
        ...

    async def acknowledge(self, uid: str, *, actor: str, comment: str) -> Alarm:
        """Acknowledge one alarm occurrence, audited with ``actor``; raises KeyError for an unknown uid."""
        ...
