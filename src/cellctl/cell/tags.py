"""PackML enumerations with the PackTags v3.0 integers used on the wire (REST, Modbus, dashboard).

Numbering from PackTags v3.0 (as Beckhoff Tc3_PackML and SEW publish it); other schemes (OPC 30060,
ros-industrial packml) number differently and must not be used here.
"""

from __future__ import annotations

import enum


class PackMLState(enum.IntEnum):
    """``Status.StateCurrent``."""

    UNDEFINED = 0
    CLEARING = 1
    STOPPED = 2
    STARTING = 3
    IDLE = 4
    SUSPENDED = 5
    EXECUTE = 6
    STOPPING = 7
    ABORTING = 8
    ABORTED = 9
    HOLDING = 10
    HELD = 11
    UNHOLDING = 12
    SUSPENDING = 13
    UNSUSPENDING = 14
    RESETTING = 15
    COMPLETING = 16
    COMPLETE = 17


class PackMLCommand(enum.IntEnum):
    """``Command.CntrlCmd``."""

    UNDEFINED = 0
    RESET = 1
    START = 2
    STOP = 3
    HOLD = 4
    UNHOLD = 5
    SUSPEND = 6
    UNSUSPEND = 7
    ABORT = 8
    CLEAR = 9
    COMPLETE = 10


class UnitMode(enum.IntEnum):
    """``Status.UnitModeCurrent``: 0 invalid, 1 production, 2 maintenance, 3 manual."""

    INVALID = 0
    PRODUCTION = 1
    MAINTENANCE = 2
    MANUAL = 3


class CycleStep(enum.IntEnum):
    """The cycle's sub-steps of Execute (PackML leaves process steps to the machine)."""

    NONE = 0
    CALIBRATE = 1
    ALIGN = 2
    SHOOT = 3
    COMPENSATE = 4
    INSTALL = 5


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
