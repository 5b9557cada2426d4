"""The moves calibration data is collected with (cellctl.commissioning.procedures): move, wait, read back.

Every robot pose stored is the one the controller reports after the move (its belief), read
back only once the move has finished, so pose and image (or distance) belong together. Every
device call carries an explicit timeout. A move the robot refuses (out of reach) drops that
sample with its reason instead of ending the collection.
"""

from __future__ import annotations

from collections.abc import Callable

from cellctl.config.calibration_procedure import MotionSettings
from cellctl.geometry.pose import Pose
from cellctl.ports import CartesianPose, DeviceRejected, MotionRequest, Robot

Progress = Callable[[int, int, str], None]


def _quiet(done: int, total: int, what: str) -> None:
    return None


async def move_and_report(robot: Robot, target: Pose, motion: MotionSettings) -> Pose:
    """Move (joint interpolation, to a fine point) and return the pose the controller reports there."""
    request = MotionRequest(CartesianPose.from_matrix(target), "joint", motion.speed_mm_s, motion.speed_deg_s)
    await robot.move(request, timeout_s=motion.move_timeout_s)
    reported = await robot.read_pose(timeout_s=motion.read_timeout_s)
    return reported.to_matrix()


async def move_or_skip(
    robot: Robot, target: Pose, motion: MotionSettings, skipped: list[str], label: str,
    step: tuple[int, int] | None, progress: Progress = _quiet, refused: str = "the robot refused the pose",
) -> Pose | None:  # fmt: skip
    """``move_and_report``, or None when the robot refuses: ``skipped`` gets why (and ``progress``, at ``step``)."""
    try:
        return await move_and_report(robot, target, motion)
    except DeviceRejected as err:
        skipped.append(f"{label}: {refused} ({err})")
        if step is not None:
            progress(*step, f"{label}: refused by the robot")
        return None
