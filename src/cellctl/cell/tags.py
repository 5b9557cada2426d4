"""PackML enumerations with the PackTags v3.0 integers, and the way back to Execute.

The enumerations (:class:`PackMLState`, :class:`PackMLCommand`, :class:`UnitMode`,
:class:`CycleStep`) are defined in :mod:`cellctl.domain`, below both the cell and the store, and
re-exported here for the cell's callers.
"""

from __future__ import annotations

from cellctl.domain import CycleStep, PackMLCommand, PackMLState, UnitMode

__all__ = ["TO_EXECUTE", "CycleStep", "PackMLCommand", "PackMLState", "UnitMode"]

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
