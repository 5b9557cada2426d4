"""The alarm tables: what each fault does to the cell, and what each alarm code means.

Two tables are the single sources of truth here:

- :data:`REACTIONS`: fault class -> the PackML command the cell issues (cell_conventions.md 1.3):
  vision/measurement NOK or operator intervention -> Hold (internal, the operator fixes it);
  external conditions (no car, PLC not ready) -> Suspend (resumes when the condition clears);
  robot/controller fault, or the PLC heartbeat lost while the robot moves -> Abort.
- :data:`ALARM_CATALOGUE`: alarm code (PackML ``Alarm.ID``) -> fault class, text, and whether
  the alarm is a *condition* (active until its source clears it, e.g. a lost link) or an *event*
  (latched: active until acknowledged, e.g. a corner not found).

The codes, fault classes and severities themselves are enumerations of :mod:`cellctl.domain`
(the store keeps them in its alarm records). :class:`cellctl.cell.alarms.AlarmManager` applies
these tables; ``docs/alarm_reactions.md`` is rendered from them by :mod:`cellctl.cell.alarms_doc`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

from cellctl.domain import AlarmCode, FaultClass, PackMLCommand, Severity

C = PackMLCommand


@dataclass(frozen=True)
class Reaction:
    """The command for a fault class, with the robot standing still or moving."""

    when_still: PackMLCommand | None
    when_moving: PackMLCommand | None
    severity: Severity
    why: str

    def command(self, robot_moving: bool) -> PackMLCommand | None:
        return self.when_moving if robot_moving else self.when_still


REACTIONS: Mapping[FaultClass, Reaction] = MappingProxyType(
    {
        FaultClass.MEASUREMENT_NOK: Reaction(
            C.HOLD, C.HOLD, Severity.ERROR, "vision or measurement NOK: internal, the operator fixes it"
        ),
        FaultClass.OPERATOR_INTERVENTION: Reaction(
            C.HOLD, C.HOLD, Severity.ERROR, "needs an operator decision: internal, the operator fixes it"
        ),
        FaultClass.SENSOR_LOST: Reaction(
            C.HOLD, C.HOLD, Severity.ERROR, "laser or camera link lost: the cell cannot measure until it is back"
        ),
        FaultClass.EXTERNAL_CONDITION: Reaction(
            C.SUSPEND, C.SUSPEND, Severity.ERROR, "no car in position, PLC not ready: external, resumes when it clears"
        ),
        FaultClass.PLC_HEARTBEAT_LOST: Reaction(
            C.HOLD, C.ABORT, Severity.CRITICAL, "line PLC silent: Hold if the robot stands still, Abort if it moves"
        ),
        FaultClass.ROBOT_FAULT: Reaction(
            C.ABORT, C.ABORT, Severity.CRITICAL, "robot or controller fault, or its link lost"
        ),
        FaultClass.SOFTWARE_FAULT: Reaction(
            C.ABORT, C.ABORT, Severity.CRITICAL, "a supervised task of the cell died"
        ),
        FaultClass.WARNING: Reaction(None, None, Severity.WARNING, "shown and logged; no state change"),
    }
)


@dataclass(frozen=True)
class AlarmSpec:
    fault_class: FaultClass
    text: str
    condition: bool  # True: active until cleared by its source; False: latched until acknowledged


ALARM_CATALOGUE: Mapping[AlarmCode, AlarmSpec] = MappingProxyType(
    {
        # Each text: the symptom, then what the operator does (the PackML commands last; the detail follows it).
        AlarmCode.LASER_LOST: AlarmSpec(
            FaultClass.SENSOR_LOST,
            "Laser sensor link lost: check its power, cable and USB serial adapter (devices.laser.port); once it is "
            "back, Unhold",
            True,
        ),
        AlarmCode.CAMERA_LOST: AlarmSpec(
            FaultClass.SENSOR_LOST, "Camera link lost: check its power, cable and network; once it is back, Unhold", True
        ),
        AlarmCode.ROBOT_LOST: AlarmSpec(
            FaultClass.ROBOT_FAULT,
            "Robot controller link lost: check the controller, its CellctlServer RAPID task and the network, where the "
            "robot stands and the glass; once it is back, Clear, Reset, Start",
            True,
        ),
        # What a cycle saw fail (an event: acknowledge it); the link itself is the watchdog's 1101/1102.
        AlarmCode.LASER_READ_FAILED: AlarmSpec(
            FaultClass.SENSOR_LOST,
            "A laser reading failed during the cycle: check the laser, its cable and the car body in front of it; "
            "acknowledge, then Unhold",
            False,
        ),
        AlarmCode.CAMERA_GRAB_FAILED: AlarmSpec(
            FaultClass.SENSOR_LOST,
            "A camera grab failed during the cycle: check the camera, its cable and the lighting; acknowledge, then Unhold",
            False,
        ),
        AlarmCode.PLC_HEARTBEAT_LOST: AlarmSpec(
            FaultClass.PLC_HEARTBEAT_LOST,
            "Line PLC heartbeat lost: check the PLC and its network; once it is back, Unhold, or after an Abort "
            "check the robot and the glass, then Clear, Reset, Start",
            True,
        ),
        AlarmCode.PLC_NOT_READY: AlarmSpec(
            FaultClass.EXTERNAL_CONDITION, "Line PLC not ready: check the line; once it is ready, Unsuspend", True
        ),
        AlarmCode.NO_CAR_IN_POSITION: AlarmSpec(
            FaultClass.EXTERNAL_CONDITION,
            "No car body in position: check the conveyor and the clamping; once it is in place, Unsuspend",
            True,
        ),
        AlarmCode.ALIGNMENT_FAILED: AlarmSpec(
            FaultClass.MEASUREMENT_NOK,
            "Laser alignment failed: check the car body is in position and the laser sees the wall; acknowledge, "
            "then Unhold",
            False,
        ),
        AlarmCode.CORNER_NOT_FOUND: AlarmSpec(
            FaultClass.MEASUREMENT_NOK,
            "Opening corner not found in the image: check the car body's position, the lighting and the cycle's "
            "image; acknowledge, then Unhold",
            False,
        ),
        AlarmCode.RESIDUAL_OVER_LIMIT: AlarmSpec(
            FaultClass.MEASUREMENT_NOK,
            "Verification shot residual above the threshold: check the robot holds its pose and the camera is "
            "steady; acknowledge, then Unhold",
            False,
        ),
        AlarmCode.CORRECTION_LIMIT_EXCEEDED: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION,
            "Correction larger than the configured limit: check the car body's position and clamping; acknowledge, "
            "then Unhold",
            False,
        ),
        AlarmCode.CALIBRATION_INVALID: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION,
            "Calibration set incomplete, invalid or out of date: Stop, redo what `cellctl calibrate status` names; "
            "acknowledge, Reset, Start",
            False,
        ),
        AlarmCode.CYCLE_INTERRUPTED: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION,
            "A cycle was interrupted by a restart: inspect the part and the glass, then acknowledge; Clear, Reset, Start",
            False,
        ),
        AlarmCode.CALIBRATION_DRIFT: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION,
            "Calibration check: camera or laser moved beyond the limit, recalibrate what it names, then acknowledge",
            False,
        ),
        AlarmCode.INSTALL_OUT_OF_TOLERANCE: AlarmSpec(
            FaultClass.MEASUREMENT_NOK,
            "Installed glass measured outside the tolerance: inspect and rework the part; acknowledge, then Unhold",
            False,
        ),
        AlarmCode.INSPECTION_FAILED: AlarmSpec(
            FaultClass.MEASUREMENT_NOK,
            "The installed glass could not be measured: inspect the part by hand; acknowledge, then Unhold",
            False,
        ),
        AlarmCode.SPC_DRIFT: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION,
            "Install offset drifting beyond its limit: Stop, run `cellctl calibrate verify`, then recalibrate; "
            "acknowledge, Reset, Start",
            False,
        ),
        AlarmCode.CYCLE_STOPPED: AlarmSpec(
            FaultClass.WARNING,
            "Cycle stopped by a PackML command (the code a stopped cycle reports; never raised): inspect the part, "
            "then Reset, Start",
            False,
        ),
        AlarmCode.NOT_IN_EXECUTE: AlarmSpec(
            FaultClass.WARNING,
            "Cycle refused: the cell is not in Execute, or is in Manual mode (the code of that refusal; never "
            "raised): leave Manual mode, bring the cell to Execute",
            False,
        ),
        AlarmCode.RECIPE_NOT_TAUGHT: AlarmSpec(
            FaultClass.WARNING,
            "Cycle refused: its recipe is not taught or its own parts not ready (the code of that refusal; never "
            "raised): teach it with `cellctl teach --recipe NAME`, as `cellctl calibrate status` says",
            False,
        ),
        AlarmCode.CALIBRATION_CHECK_DUE: AlarmSpec(
            FaultClass.WARNING, "Calibration check due: run `cellctl calibrate verify`", True
        ),
        AlarmCode.ROBOT_FAULT: AlarmSpec(
            FaultClass.ROBOT_FAULT,
            "Robot refused or interrupted a motion: check the controller's messages, where the robot stands and the "
            "glass; acknowledge, then Clear, Reset, Start",
            False,
        ),
        AlarmCode.POSITION_FEEDBACK_LOST: AlarmSpec(
            FaultClass.ROBOT_FAULT,
            "Robot position feedback (EGM) lost on the move, robot stopped: check the side the reason names (the "
            "controller, the EGM link, a loaded cell PC), where the robot stands and the glass; acknowledge, then "
            "Clear, Reset, Start",
            False,
        ),
        AlarmCode.TASK_FAILED: AlarmSpec(
            FaultClass.SOFTWARE_FAULT,
            "A cell task failed: see the service log, check where the robot stands and the glass; acknowledge, then "
            "Clear, Reset, Start",
            False,
        ),
        AlarmCode.DEVICE_SLOW: AlarmSpec(
            FaultClass.WARNING, "Device missed a watchdog ping: if it recurs, check its link and load", True
        ),
        # The store's disk ([store.retention] disk_warn_free_gb / disk_stop_free_gb): a warning first, then
        # a Hold so production stops while records and images can still be written; cleared when space is back.
        AlarmCode.DISK_SPACE_LOW: AlarmSpec(
            FaultClass.WARNING, "Disk space low for the store and images: free space or lower the retention", True
        ),
        AlarmCode.DISK_SPACE_CRITICAL: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION,
            "Disk almost full: production held before the store's writes fail; free space, then Unhold",
            True,
        ),
        # A finished cycle's record the store refused (disk full, lock held): kept in memory and written again;
        # production held meanwhile, so no glass is installed without its record. Cleared once it is written.
        AlarmCode.RECORD_WRITE_FAILED: AlarmSpec(
            FaultClass.OPERATOR_INTERVENTION,
            "A record (a cycle's, an audit entry, an alarm) could not be written to the store, kept in memory: production "
            "held until it is; check the disk, another process holding the database's lock and the service log; Unhold "
            "once it is written",
            True,
        ),
    }
)

RECOVERY_COMMANDS: frozenset[PackMLCommand] = frozenset({C.RESET, C.START, C.UNHOLD, C.UNSUSPEND})
"""Refused while an alarm with a reaction is active."""

STOP_REASON_RESET_COMMANDS: frozenset[PackMLCommand] = frozenset({C.RESET, C.UNHOLD, C.UNSUSPEND})
"""Accepting one of these ends the stop, so the first-out stop reason is released."""


def reaction_for(fault_class: FaultClass, *, robot_moving: bool) -> PackMLCommand | None:
    """The PackML command :data:`REACTIONS` prescribes."""
    return REACTIONS[fault_class].command(robot_moving)
