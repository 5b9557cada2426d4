"""Collecting calibration data through the device ports: move, wait, read back, measure.

Every robot pose stored is the one the controller reports after the move (its belief), read
back only once the move has finished, so pose and image (or distance) belong together. Every
device call carries an explicit timeout. A move the robot refuses (out of reach) or a reading
without a value drops that sample with its reason instead of ending the collection.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cellctl.ports import (
    Camera,
    CartesianPose,
    DeviceRejected,
    DisplacementSensor,
    LaserStatus,
    MotionRequest,
    Robot,
)
from cellctl.geometry.pose import Pose

Progress = Callable[[int, int, str], None]


def _quiet(done: int, total: int, what: str) -> None:
    return None


@dataclass(frozen=True)
class MotionSettings:
    """Speeds and timeouts of the collection moves and reads."""

    speed_mm_s: float = 250.0
    speed_deg_s: float = 30.0
    move_timeout_s: float = 60.0
    read_timeout_s: float = 5.0
    grab_timeout_s: float = 10.0


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


@dataclass
class ImageSamples:
    """Frames with the flange pose reported at each, and the targets the robot refused."""

    names: list[str] = field(default_factory=list)
    images: list[NDArray[np.uint8]] = field(default_factory=list)
    T_B_H: list[Pose] = field(default_factory=list)
    targets: list[Pose] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)


async def collect_images(
    robot: Robot,
    camera: Camera,
    targets: Sequence[Pose],
    motion: MotionSettings,
    *,
    prefix: str = "view",
    progress: Progress = _quiet,
) -> ImageSamples:
    """Visit each target, grab one frame there and keep it with the reported flange pose."""
    out = ImageSamples()
    n = len(targets)
    for k, X in enumerate(targets):
        name = f"{prefix}_{k:03d}"
        reported = await move_or_skip(robot, X, motion, out.skipped, name, (k + 1, n), progress)
        if reported is None:
            continue
        frame = await camera.grab(timeout_s=motion.grab_timeout_s)
        out.names.append(name)
        out.images.append(frame.image)
        out.T_B_H.append(reported)
        out.targets.append(np.asarray(X, dtype=float))
        progress(k + 1, n, f"{name}: frame {frame.frame_id}")
    return out


@dataclass
class LaserSamples:
    """Distances with the flange pose reported at each; readings without a value are kept with their status."""

    T_B_H: list[Pose] = field(default_factory=list)
    distances_mm: list[float | None] = field(default_factory=list)
    statuses: list[str] = field(default_factory=list)
    groups: list[int] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)


async def collect_distances(
    robot: Robot,
    laser: DisplacementSensor,
    targets: Sequence[Pose],
    groups: Sequence[int],
    motion: MotionSettings,
    *,
    progress: Progress = _quiet,
) -> LaserSamples:
    """Visit each target and read the laser once the robot stands still there."""
    out = LaserSamples()
    n = len(targets)
    for k, (X, g) in enumerate(zip(targets, groups)):
        reported = await move_or_skip(
            robot, X, motion, out.skipped, f"pose {k}", (k + 1, n), progress, refused="the robot refused it"
        )
        if reported is None:
            continue
        reading = await laser.read(timeout_s=motion.read_timeout_s)
        out.T_B_H.append(reported)
        out.distances_mm.append(reading.distance_mm if reading.status is LaserStatus.OK else None)
        out.statuses.append(reading.status.value)
        out.groups.append(int(g))
        if k % 10 == 9 or k + 1 == n:
            progress(k + 1, n, f"pose {k}: {reading.status.value}")
    return out
