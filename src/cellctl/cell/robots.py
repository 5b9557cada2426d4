"""Robot ports that wrap the cell's robot: one that knows when it moves, one that keeps to a speed limit."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from cellctl.ports import (
    CartesianPose,
    DeviceRejected,
    FineCorrection,
    Identified,
    MotionRequest,
    PoseStream,
    Robot,
    RobotState,
)


class RobotProxy:
    """A Robot port passing every call to ``robot``; subclasses change what they need."""

    def __init__(self, robot: Robot) -> None:
        self._robot = robot

    @property
    def inner(self) -> Robot:
        """The robot this proxy passes its calls to."""
        return self._robot

    async def move(self, request: MotionRequest, *, timeout_s: float) -> CartesianPose:
        return await self._robot.move(request, timeout_s=timeout_s)

    async def read_pose(self, *, timeout_s: float) -> CartesianPose:
        return await self._robot.read_pose(timeout_s=timeout_s)

    async def state(self, *, timeout_s: float) -> RobotState:
        return await self._robot.state(timeout_s=timeout_s)

    async def stop(self, *, timeout_s: float) -> None:
        await self._robot.stop(timeout_s=timeout_s)

    async def set_gripper(self, hold: bool, *, timeout_s: float) -> None:
        await self._robot.set_gripper(hold, timeout_s=timeout_s)

    async def ping(self, *, timeout_s: float) -> float:
        return await self._robot.ping(timeout_s=timeout_s)

    async def close(self) -> None:
        await self._robot.close()

    def identity(self) -> dict[str, str]:
        """The wrapped robot's (Identified port), or its kind when it says nothing."""
        inner = self._robot
        return dict(inner.identity()) if isinstance(inner, Identified) else {"kind": type(inner).__name__}


class MotionHalted(DeviceRejected):
    """A motion or gripper change asked for while the cell stops its running cycle (a Hold, Stop or Abort came)."""


class TrackedRobot(RobotProxy):
    """A Robot port that knows whether a motion is under way (for alarm reactions), and that refuses every new
    motion and gripper change while halted (:meth:`halt`: the cell is ending its running cycle)."""

    def __init__(self, robot: Robot) -> None:
        super().__init__(robot)
        self._moves = 0
        self._halted: str | None = None

    @property
    def moving(self) -> bool:
        return self._moves > 0

    @property
    def halted(self) -> bool:
        return self._halted is not None

    def halt(self, why: str) -> None:
        """From now until :meth:`resume`, :meth:`move`, :meth:`set_gripper` and :meth:`in_motion` raise MotionHalted."""
        self._halted = why

    def resume(self) -> None:
        self._halted = None

    def _refuse_if_halted(self, what: str) -> None:
        if self._halted is not None:
            raise MotionHalted("robot", f"{what} refused: the cell is stopping its cycle ({self._halted})")

    async def move(self, request: MotionRequest, *, timeout_s: float) -> CartesianPose:
        with self.in_motion():
            return await self._robot.move(request, timeout_s=timeout_s)

    async def set_gripper(self, hold: bool, *, timeout_s: float) -> None:
        self._refuse_if_halted("closing the gripper" if hold else "releasing the glass")
        await self._robot.set_gripper(hold, timeout_s=timeout_s)

    @contextlib.contextmanager
    def in_motion(self) -> Iterator[None]:
        """Count the robot as moving meanwhile (a move, or an EGM correction, which is not a move() call)."""
        self._refuse_if_halted("a motion")
        self._moves += 1
        try:
            yield
        finally:
            self._moves -= 1


class ReducedSpeedRobot(RobotProxy):
    """The Robot port of a commissioning job: every move capped at the procedure's reduced speed."""

    def __init__(self, robot: Robot, max_mm_s: float, max_deg_s: float) -> None:
        super().__init__(robot)
        self.max_mm_s = float(max_mm_s)
        self.max_deg_s = float(max_deg_s)

    async def move(self, request: MotionRequest, *, timeout_s: float) -> CartesianPose:
        capped = MotionRequest(request.target, request.kind, min(request.speed_mm_s, self.max_mm_s), min(request.speed_deg_s, self.max_deg_s))
        return await self._robot.move(capped, timeout_s=timeout_s)

    async def set_gripper(self, hold: bool, *, timeout_s: float) -> None:
        """Refused: commissioning (calibration, teaching) keeps the glass on the gripper throughout."""
        raise DeviceRejected("robot", "the gripper is not switched during commissioning: the glass stays on the gripper")

    async def close(self) -> None:
        return None  # the service owns the robot


def fine_correction_of(robot: Robot) -> FineCorrection | None:
    """The robot's streaming fine correction (ABB EGM, through any proxies), or None when its driver has none."""
    while isinstance(robot, RobotProxy):
        robot = robot.inner
    return robot if isinstance(robot, FineCorrection) else None


def pose_stream_of(robot: Robot) -> PoseStream | None:
    """The robot's position feedback stream (through any proxies), or None when its driver has none."""
    while isinstance(robot, RobotProxy):
        robot = robot.inner
    return robot if isinstance(robot, PoseStream) else None
