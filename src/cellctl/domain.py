"""The plain values the cell and the store share: PackML enumerations, machine events, alarm records.

Everything here is an enumeration or a frozen record, with no behaviour beyond reading itself. It
sits below both :mod:`cellctl.cell` (which makes these values) and :mod:`cellctl.store` (which
keeps them), so the store never imports the cell. It imports nothing from cellctl.

The logic stays with the cell: the state model in :mod:`cellctl.cell.packml`, the alarm reaction
table and catalogue in :mod:`cellctl.cell.alarm_table`, the alarm manager in
:mod:`cellctl.cell.alarms`. Those modules re-export the names defined here, so
``from cellctl.cell.tags import CycleStep`` and ``from cellctl.cell.alarms import Alarm`` keep working.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, fields
from datetime import datetime

# --- PackML enumerations -------------------------------------------------------------------------
#
# The PackTags v3.0 integers used on the wire (REST, Modbus, dashboard). Numbering from PackTags
# v3.0 (as Beckhoff Tc3_PackML and SEW publish it); other schemes (OPC 30060, ros-industrial
# packml) number differently and must not be used here.


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
    INSPECT = 6


# --- Machine events ------------------------------------------------------------------------------


class EventKind(enum.Enum):
    COMMAND = "command"
    STATE_COMPLETE = "state_complete"
    MODE = "mode"
    CYCLE_STEP = "cycle_step"


@dataclass(frozen=True)
class MachineEvent:
    """One change of the machine, with everything before and after (for the audit log and SSE).

    ``seq`` increases by one per event of this machine; ``at`` is UTC wall time.
    """

    seq: int
    kind: EventKind
    at: datetime
    actor: str
    source: str
    state_before: PackMLState
    state_after: PackMLState
    mode_before: UnitMode
    mode_after: UnitMode
    step_before: CycleStep
    step_after: CycleStep
    command: PackMLCommand | None = None

    @property
    def state_changed(self) -> bool:
        return self.state_before != self.state_after


# --- Alarm records -------------------------------------------------------------------------------


class FaultClass(enum.IntEnum):
    """What kind of fault; the value is the PackML alarm ``Category``."""

    MEASUREMENT_NOK = 1
    OPERATOR_INTERVENTION = 2
    SENSOR_LOST = 3
    EXTERNAL_CONDITION = 4
    PLC_HEARTBEAT_LOST = 5
    ROBOT_FAULT = 6
    SOFTWARE_FAULT = 7
    WARNING = 8


class Severity(enum.IntEnum):
    WARNING = 1  # shown and logged, no state change
    ERROR = 2  # production pauses (Hold or Suspend)
    CRITICAL = 3  # the cell aborts (or may, e.g. heartbeat lost while moving)


class AlarmCode(enum.IntEnum):
    """PackML ``Alarm.ID`` values of this cell (the thousands group the fault family).

    What each code means (fault class, text, condition or event) is
    :data:`cellctl.cell.alarm_table.ALARM_CATALOGUE`.
    """

    LASER_LOST = 1101
    CAMERA_LOST = 1102
    ROBOT_LOST = 1103
    LASER_READ_FAILED = 1104
    CAMERA_GRAB_FAILED = 1105
    PLC_HEARTBEAT_LOST = 1201
    PLC_NOT_READY = 1202
    NO_CAR_IN_POSITION = 1203
    ALIGNMENT_FAILED = 1301
    CORNER_NOT_FOUND = 1302
    RESIDUAL_OVER_LIMIT = 1303
    CORRECTION_LIMIT_EXCEEDED = 1304
    CALIBRATION_INVALID = 1305
    CYCLE_INTERRUPTED = 1306
    CALIBRATION_DRIFT = 1307
    CALIBRATION_CHECK_DUE = 1308
    CYCLE_STOPPED = 1309
    NOT_IN_EXECUTE = 1310
    INSTALL_OUT_OF_TOLERANCE = 1311
    INSPECTION_FAILED = 1312
    SPC_DRIFT = 1313
    RECIPE_NOT_TAUGHT = 1314
    ROBOT_FAULT = 1401
    POSITION_FEEDBACK_LOST = 1402
    TASK_FAILED = 1501
    DEVICE_SLOW = 1601
    DISK_SPACE_LOW = 1701
    DISK_SPACE_CRITICAL = 1702
    RECORD_WRITE_FAILED = 1703


@dataclass(frozen=True)
class Alarm:
    """One alarm occurrence (PackML ``PackMLAlarmDataType`` plus what the cell needs).

    Attributes:
        uid: unique id of this occurrence (the store's key, the API's ``/alarms/{uid}``).
        code: PackML ``ID`` (an :class:`AlarmCode`).
        value: PackML ``Value``, a sub-code (e.g. the device's own error code), 0 if none.
        message: PackML ``Message``: the catalogue text and the detail.
        category: PackML ``Category``: the fault class.
        severity: from :data:`cellctl.cell.alarm_table.REACTIONS`.
        source: what raised it in the cell's words (``laser``, ``plc``, ``cycle``...).
        raised_at: PackML ``DateTime`` (UTC).
        ack_at / ack_by: PackML ``AckDateTime`` and who acknowledged.
        active: PackML ``Trigger``.
        condition: True for a condition alarm (cleared by its source), False for a latched event.
        cleared_at: when it went inactive.
        reaction: the command the cell issued for it, None if none was (needed).
        cycle_id: the cycle it happened in, if any.
    """

    uid: str
    code: AlarmCode
    value: int
    message: str
    category: FaultClass
    severity: Severity
    source: str
    raised_at: datetime
    active: bool = True
    condition: bool = True
    ack_at: datetime | None = None
    ack_by: str | None = None
    cleared_at: datetime | None = None
    reaction: PackMLCommand | None = None
    cycle_id: int | None = None

    @property
    def acknowledged(self) -> bool:
        return self.ack_at is not None

    @property
    def listed(self) -> bool:
        """Shown among the current alarms: active, or gone but not yet acknowledged."""
        return self.active or not self.acknowledged

    def summary(self) -> str:
        return f"alarm {self.code.value} ({self.message}) from {self.source}"


@dataclass(frozen=True)
class InstallDeviation:
    """The paper's six figures of one install in the workpiece frame T: offsets in mm, rotations in deg."""

    dx_mm: float
    dy_mm: float
    dz_mm: float
    drx_deg: float
    dry_deg: float
    drz_deg: float


DEVIATION_KEYS: tuple[str, ...] = tuple(f.name for f in fields(InstallDeviation))
"""The six figures' names in order: ``dx_mm, dy_mm, dz_mm, drx_deg, dry_deg, drz_deg``."""
