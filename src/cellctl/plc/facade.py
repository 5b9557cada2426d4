"""What the PLC interface needs from the rest of the cell, and the values it exchanges.

The PLC server knows the cell only through ``CellFacade``; the service's composition root
implements it over the orchestrator and the store. Values cross this boundary in the cell's inner
units (mm, radians, seconds); the PLC interface converts to the register map's units (deg, ms).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from cellctl.domain import CycleStep, PackMLCommand, PackMLState, UnitMode
from cellctl.plc.register_map import CommandReply, PlcErrorCode

__all__ = [
    "CellFacade",
    "CellStatus",
    "CommandReply",
    "CycleAcceptance",
    "CycleOutcome",
    "PlcErrorCode",
]

UINT16_MAX = 0xFFFF
UINT32_MAX = 0xFFFF_FFFF


def _check_uint(name: str, value: int, hi: int, *, nonzero: bool = False) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= hi:
        raise ValueError(f"{name} must be an integer in 0..{hi}, got {value!r}")
    if nonzero and value == 0:
        raise ValueError(f"{name} must be nonzero")


@dataclass(frozen=True)
class CellStatus:
    """A snapshot of the cell for the PLC's status words."""

    state: PackMLState
    unit_mode: UnitMode
    cycle_step: CycleStep
    stop_reason_id: int
    """First-out alarm / stop reason id, 0 when none."""
    ready_for_cycle: bool
    """The cell would accept start_cycle now."""
    interlock_alarm_id: int = 0
    """The first active alarm that holds back Reset, Start, Unhold and Unsuspend (cmd_result 5), 0 when none."""
    robot_clear: bool = False
    """No cycle runs and the robot's flange stands at least ``[plc] clear_distance_mm`` in front of the car
    body's wall (False when unknown): the line may move the car body."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "state", PackMLState(self.state))
        object.__setattr__(self, "unit_mode", UnitMode(self.unit_mode))
        object.__setattr__(self, "cycle_step", CycleStep(self.cycle_step))
        _check_uint("stop_reason_id", self.stop_reason_id, UINT16_MAX)
        _check_uint("interlock_alarm_id", self.interlock_alarm_id, UINT16_MAX)


@dataclass(frozen=True)
class CycleAcceptance:
    """The answer to start_cycle: accepted, or refused with an error code (alarm / stop-reason id)."""

    accepted: bool
    error_code: int = 0
    reason: str = ""

    def __post_init__(self) -> None:
        _check_uint("error_code", self.error_code, UINT16_MAX)
        if self.accepted and self.error_code != 0:
            raise ValueError("an accepted cycle has error_code 0")
        if not self.accepted and self.error_code == 0:
            raise ValueError("a refused cycle needs a nonzero error_code saying why")


@dataclass(frozen=True)
class CycleOutcome:
    """The result of one cycle, as stored by the cell and published to the PLC.

    The corrections are the install pose minus the taught install pose in the workpiece frame:
    translations in mm, rotations in radians as XYZ fixed angles (eq. 13). A failed cycle (``ok``
    False) carries the alarm / stop-reason id in ``error_code`` and whatever corrections it had
    (0 if none). ``car_body_id`` is the request's car body (0: none given); ``install_started`` says
    the cycle had commanded the robot to install its glass (the record's ``install_started_at``).
    """

    req_id: int
    recipe_id: int
    part_id: int
    ok: bool
    error_code: int
    dx_mm: float
    dy_mm: float
    dz_mm: float
    drx_rad: float
    dry_rad: float
    drz_rad: float
    cycle_time_s: float
    measured: tuple[float, float, float, float, float, float] | None = None
    measured_ok: bool | None = None
    car_body_id: int = 0
    install_started: bool = False

    def __post_init__(self) -> None:
        _check_uint("req_id", self.req_id, UINT32_MAX, nonzero=True)
        _check_uint("recipe_id", self.recipe_id, UINT16_MAX)
        _check_uint("part_id", self.part_id, UINT32_MAX)
        _check_uint("car_body_id", self.car_body_id, UINT32_MAX)
        if not isinstance(self.install_started, bool):
            raise ValueError(f"cycle {self.req_id}: install_started must be True or False, got {self.install_started!r}")
        _check_uint("error_code", self.error_code, UINT16_MAX)
        if self.ok != (self.error_code == 0):
            raise ValueError(f"cycle {self.req_id}: ok={self.ok} but error_code={self.error_code}; "
                             "an ok cycle has error_code 0 and a failed one a nonzero code")
        for name in ("dx_mm", "dy_mm", "dz_mm", "drx_rad", "dry_rad", "drz_rad", "cycle_time_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
                raise ValueError(f"cycle {self.req_id}: {name} must be a finite number, got {v!r}")
        if self.cycle_time_s < 0:
            raise ValueError(f"cycle {self.req_id}: cycle_time_s must be >= 0, got {self.cycle_time_s}")
        if (self.measured is None) != (self.measured_ok is None):
            raise ValueError(f"cycle {self.req_id}: give measured and measured_ok together (or neither)")
        if self.measured is not None and (len(self.measured) != 6 or not all(math.isfinite(v) for v in self.measured)):
            raise ValueError(f"cycle {self.req_id}: measured must be six finite numbers (dx, dy, dz mm; drx, dry, drz deg)")

    @property
    def inspection_status(self) -> int:
        """The ``inspection_status`` register: 0 not measured, 1 within the tolerance, 2 outside it."""
        return 0 if self.measured_ok is None else (1 if self.measured_ok else 2)


@runtime_checkable
class CellFacade(Protocol):
    """The cell as the PLC interface sees it. Implemented by the service over the orchestrator.

    Contract:
    - ``status`` is cheap and never blocks (it is read every scan); its ``robot_clear`` is False
      whenever the facade does not know better.
    - ``start_cycle`` returns promptly (within the configured facade_timeout_s) once the cycle is
      accepted or refused; the cycle itself runs in the cell's own task, never in the caller's.
      It is idempotent per ``req_id``: for an id that is running or finished it starts nothing and
      answers accepted. ``car_body_id`` (0: none) comes by keyword, and only when the PLC gave one,
      so a facade without it still serves PLCs that give none. A refusal carries a nonzero code:
      ``PlcErrorCode`` 905-908 (unknown recipe, not ready, id in use, recipe not taught) or one of
      the cell's alarm ids; never a code that claims a fault the cell does not have.
    - ``result_of`` returns the stored outcome of ``req_id`` once that cycle has finished (also
      across restarts, from the store), else None. Every accepted cycle ends in an outcome
      (ok, failed, aborted or interrupted). A refusal is the id's outcome too: store it (ok False,
      its code, the request's recipe, part and car body, no corrections, no time) so that
      ``result_of`` returns it and a repeated id republishes it; the PLC interface also remembers
      refusals while it runs. An outcome says whether the cycle had started its install.
    - ``command`` / ``change_mode`` return once the request is accepted or refused (not when the
      state machine has settled).
    - ``plc_link_lost`` / ``plc_link_restored`` report the PLC heartbeat; the cell maps them to an
      alarm (and to Hold / Abort as its fault policy says). They must not block.
    """

    def status(self) -> CellStatus: ...

    async def start_cycle(self, req_id: int, recipe_id: int, part_id: int, car_body_id: int = 0) -> CycleAcceptance: ...

    async def result_of(self, req_id: int) -> CycleOutcome | None: ...

    async def command(self, command: PackMLCommand) -> CommandReply: ...

    async def change_mode(self, mode: UnitMode) -> CommandReply: ...

    def plc_link_lost(self, silent_for_s: float) -> None: ...

    def plc_link_restored(self) -> None: ...
