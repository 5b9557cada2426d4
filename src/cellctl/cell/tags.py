"""PackML enumerations with the PackTags v3.0 integers, and the way back to Execute.

The enumerations (:class:`PackMLState`, :class:`PackMLCommand`, :class:`UnitMode`,
:class:`CycleStep`) are defined in :mod:`cellctl.domain`, below both the cell and the store, and
re-exported here for the cell's callers.
"""

from __future__ import annotations

from cellctl.domain import CycleStep, PackMLCommand, PackMLState, UnitMode

__all__ = ["TO_EXECUTE", "CycleStep", "PackMLCommand", "PackMLState", "UnitMode", "not_ready_for_cycle"]

C = PackMLCommand
TO_EXECUTE: dict[PackMLState, tuple[PackMLCommand, ...]] = {
    PackMLState.ABORTED: (C.CLEAR, C.RESET, C.START),
    PackMLState.STOPPED: (C.RESET, C.START),
    PackMLState.COMPLETE: (C.RESET, C.START),
    PackMLState.IDLE: (C.START,),
    PackMLState.HELD: (C.UNHOLD,),
    PackMLState.SUSPENDED: (C.UNSUSPEND,),
}
"""The commands that lead from each resting state back to Execute (once its alarms are acknowledged)."""


def not_ready_for_cycle(state: PackMLState, mode: UnitMode) -> str | None:
    """Why the cell takes no cycle now (None: it does): it runs cycles in Execute, in Production or
    Maintenance; in Manual a technician works in the cell and no requester may start an install."""
    if state is PackMLState.EXECUTE and mode is not UnitMode.MANUAL:
        return None
    if state is PackMLState.EXECUTE:
        return ("the unit mode is Manual: the cell takes no automatic cycle; stop it, switch the mode to Production or "
                "Maintenance (POST /mode/production), then reset and start")
    steps = TO_EXECUTE.get(state)
    how = (" then ".join(c.name.lower() for c in steps) + " (POST /commands/<name>)") if steps else "wait until it settles"
    return f"the cell is {state.name}, not EXECUTE: {how}"
