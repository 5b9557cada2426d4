"""The verification moves without a stop (issue 19): EGM position guidance where the robot offers it.

A verification move is small (the corner's residual, tenths of a millimetre after the first
shot); a RAPID move to it starts, cruises and settles at a fine point like any other. Where the
robot's driver streams corrections (:class:`cellctl.ports.FineCorrection`, ABB EGM) the flange is
guided to the target until the controller reports it within the tolerances, under the driver's
EGM supervision (no data, a fault, no convergence: the session is stopped and the move fails).
A driver without EGM, or one that refuses the correction (larger than its EGM limits), takes the
RAPID move; the record says which each move took. A controller that refuses EGM itself (no UDPUC
device: ERR 151) is also logged, once per service run and again when its reason changes.
"""

from __future__ import annotations

import contextlib
import logging
import weakref
from typing import TYPE_CHECKING

import numpy as np

from cellctl.cell.cycle_failure import CycleFailed
from cellctl.cell.robots import TrackedRobot, fine_correction_of
from cellctl.domain import AlarmCode, CycleStep
from cellctl.geometry.pose import Pose
from cellctl.ports import CartesianPose, DeviceError, DeviceRejected

if TYPE_CHECKING:
    from cellctl.cell.cycle import CycleRun

log = logging.getLogger(__name__)

PER_MOVE = "LIMIT"
"""The refusal code of a correction larger than the driver's EGM limits: about that move, not the cell's EGM."""
_told: weakref.WeakKeyDictionary[object, str] = weakref.WeakKeyDictionary()
"""Per robot driver (one a service run): the controller's EGM refusal last logged."""


def _tell_egm_refused(guide: object, err: DeviceRejected) -> None:
    """Log once (and again when the reason changes) that the controller refuses EGM, with the fix."""
    reason = str(err)
    if err.code is None or err.code == PER_MOVE or _told.get(guide) == reason:
        return  # no code: the driver has no EGM configured (devices.robot.egm_port = 0 turns it off on purpose)
    _told[guide] = reason
    log.warning("the verification moves are RAPID moves, not EGM: the controller refuses EGM (%s). Set up its UDPUC "
                "device for egm_port (drivers/abb_robot/README.md, step 6: EGM), or set process.motion.verify_by_egm = "
                "false (devices.robot.egm_port = 0 turns EGM off altogether)", reason)  # fmt: skip


async def verification_move(run: CycleRun, step: CycleStep, target: Pose) -> tuple[Pose, str]:
    """Bring the flange to ``target``: by EGM where it can, else by a RAPID move; the pose reached and how."""
    motion = run.motion
    guide = fine_correction_of(run.dev.robot) if motion.verify_by_egm else None
    if guide is None:
        return await run.move(step, target), "rapid"
    robot = run.dev.robot
    moving = robot.in_motion() if isinstance(robot, TrackedRobot) else contextlib.nullcontext()
    try:
        with moving:  # an EGM correction moves the robot as a move does (alarm reactions ask)
            reached = await guide.correct_to(
                CartesianPose.from_matrix(target), tolerance_mm=motion.egm_tolerance_mm,
                tolerance_rad=float(np.radians(motion.egm_tolerance_deg)), timeout_s=motion.move_timeout_s,
            )  # fmt: skip
    except DeviceRejected as err:  # no EGM configured, refused by the controller, or the correction is beyond its limits
        _tell_egm_refused(guide, err)
        return await run.move(step, target), f"rapid ({err})"
    except DeviceError as err:
        raise CycleFailed(step, AlarmCode.ROBOT_FAULT, f"EGM correction failed: {err}") from err
    _told.pop(guide, None)  # EGM works (again): a later refusal is news
    return reached.to_matrix(), "egm"
