"""In-process simulated devices: the robot and the laser of a :class:`SimCell` behind the ports.

They behave as the real devices do at the port: every call takes ``timeout_s`` and raises
DeviceTimeout when the (scaled) simulated time does not fit in it; a move the robot cannot reach
is refused with UnreachableTarget before anything moves; a stop ends a move early with
MotionInterrupted; the gripper is not switched while the robot moves (DeviceRejected); the robot
reports its belief, never the truth; a laser reading without a valid distance comes back as a status. Simulated durations are multiplied by the cell's ``time_scale``.
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import Literal

from cellctl.ports import (
    CartesianPose,
    DeviceDisconnected,
    DeviceRejected,
    DeviceTimeout,
    DistanceReading,
    LaserStatus,
    MotionInterrupted,
    MotionRequest,
    RobotState,
    UnreachableTarget,
)
from cellctl.sim.cell import SimCell
from cellctl.sim.robot import Motion, ReachError, RobotBusy


def check_timeout(device: str, timeout_s: float) -> float:
    """``timeout_s`` as a float, or ValueError naming ``device`` if it is not a positive finite number (s)."""
    number = isinstance(timeout_s, (int, float)) and not isinstance(timeout_s, bool)
    if not number or not math.isfinite(timeout_s) or timeout_s <= 0:
        raise ValueError(f"{device}: timeout_s must be a positive number of seconds, got {timeout_s!r}")
    return float(timeout_s)


class _TwinDevice:
    """What the robot and the laser share at the port: the closed state and a round trip of fixed latency (s)."""

    _closed_message = "the connection is closed; create a new device to reconnect"

    def __init__(self, cell: SimCell, name: str, latency_s: float) -> None:
        self._cell = cell
        self.name = name
        self._latency_s = latency_s * cell.time_scale
        self._closed = False

    def _check_open(self) -> None:
        if self._closed:
            raise DeviceDisconnected(self.name, self._closed_message)

    async def _round_trip(self, timeout_s: float) -> None:
        if self._latency_s > timeout_s:
            await asyncio.sleep(timeout_s)
            raise DeviceTimeout(self.name, f"no answer within {timeout_s:g} s")
        await asyncio.sleep(self._latency_s)

    async def ping(self, *, timeout_s: float) -> float:
        """A harmless round trip; returns its duration in seconds."""
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        t0 = time.monotonic()
        await self._round_trip(timeout_s)
        return time.monotonic() - t0


class SimRobot(_TwinDevice):
    """The cell's robot as a :class:`cellctl.ports.Robot`.

    Args:
        cell: the simulated cell whose arm this drives.
        name: the device's name in messages.
    """

    def __init__(self, cell: SimCell, *, name: str = "robot") -> None:
        super().__init__(cell, name, cell.config.robot.call_latency_s)
        self._arm = cell.arm
        self._outcome: asyncio.Future[Literal["reached", "stopped"]] | None = None
        self._waiter: asyncio.Task[None] | None = None

    async def move(self, request: MotionRequest, *, timeout_s: float) -> CartesianPose:
        """Move to ``request.target`` (the controller's belief) and return the pose read back after it."""
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        if not isinstance(request, MotionRequest):
            raise TypeError(f"{self.name}: move needs a MotionRequest, got {type(request).__name__}")
        deadline = time.monotonic() + timeout_s
        await self._round_trip(timeout_s)
        try:
            motion = self._arm.start(
                request.target.to_matrix(), request.speed_mm_s, request.speed_deg_s, linear=request.kind == "linear"
            )
        except ReachError as err:
            raise UnreachableTarget(self.name, str(err)) from None
        except RobotBusy as err:
            raise DeviceRejected(self.name, str(err)) from None
        loop = asyncio.get_running_loop()
        outcome: asyncio.Future[Literal["reached", "stopped"]] = loop.create_future()
        self._outcome = outcome
        self._waiter = asyncio.create_task(self._wait_for_arrival(motion, outcome))
        remaining = deadline - time.monotonic()
        try:
            result = await asyncio.wait_for(asyncio.shield(outcome), max(remaining, 0.0))
        except TimeoutError:
            raise DeviceTimeout(
                self.name,
                f"motion not finished within {timeout_s:g} s (it needs {motion.t_end - motion.t_start:.3g} s); "
                "the robot is still moving",
            ) from None
        if result == "stopped":
            raise MotionInterrupted(self.name, "the motion was stopped before it reached its target")
        return CartesianPose.from_matrix(self._arm.belief_pose())

    async def _wait_for_arrival(self, motion: Motion, outcome: asyncio.Future[Literal["reached", "stopped"]]) -> None:
        await asyncio.sleep(max(motion.t_end - self._arm.now(), 0.0))
        if not outcome.done():
            outcome.set_result("reached")

    def identity(self) -> dict[str, str]:
        """The twin's robot (Identified port): which simulated cell it belongs to."""
        return {"kind": "twin robot", "seed": str(self._cell.seed)}

    async def read_pose(self, *, timeout_s: float) -> CartesianPose:
        """The flange pose the controller believes it has (interpolated while moving)."""
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        await self._round_trip(timeout_s)
        return CartesianPose.from_matrix(self._arm.belief_pose())

    async def state(self, *, timeout_s: float) -> RobotState:
        """Motors on, program running, and whether it is moving (joint angles are not modelled)."""
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        await self._round_trip(timeout_s)
        return RobotState(motors_on=True, program_running=True, moving=self._arm.moving())

    async def stop(self, *, timeout_s: float) -> None:
        """Stop the current motion where the flange is now; a move waiting on it raises MotionInterrupted."""
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        await self._round_trip(timeout_s)
        if self._arm.moving():
            self._arm.stop()
        if self._outcome is not None and not self._outcome.done():
            self._outcome.set_result("stopped")
        if self._waiter is not None:
            self._waiter.cancel()

    async def set_gripper(self, hold: bool, *, timeout_s: float) -> None:
        """Vacuum on (``hold``) or off: off lets the cell's glass go where it truly stands (installed).

        Refused while the arm moves, as the controller refuses it (DeviceRejected).
        """
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        if not isinstance(hold, bool):
            raise TypeError(f"{self.name}: set_gripper needs hold True or False, got {hold!r}")
        await self._round_trip(timeout_s)
        if self._arm.moving():
            what = "hold" if hold else "release"
            raise DeviceRejected(self.name, f"gripper {what} refused: the robot is moving; the gripper keeps its state")
        self._cell.set_gripper(hold)

    async def close(self) -> None:
        """Close the connection (the arm finishes any motion on its own). Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._outcome is not None and not self._outcome.done():
            self._outcome.set_exception(DeviceDisconnected(self.name, "connection closed during the motion"))
            self._outcome.exception()  # mark retrieved: nobody may be waiting any more
        if self._waiter is not None:
            self._waiter.cancel()


class SimDisplacementSensor(_TwinDevice):
    """The cell's LK-G500 as a :class:`cellctl.ports.DisplacementSensor`.

    Args:
        cell: the simulated cell whose laser this reads.
        head: the head (output) number reported in each reading.
        name: the device's name in messages.
    """

    _closed_message = "the port is closed; create a new device to reopen it"

    def __init__(self, cell: SimCell, *, head: int = 1, name: str = "laser") -> None:
        if head < 1:
            raise ValueError(f"head must be 1 or more, got {head}")
        super().__init__(cell, name, cell.config.laser.read_latency_s)
        self.head = head
        self._waiting = False

    def identity(self) -> dict[str, str]:
        """The twin's laser (Identified port): which simulated cell it belongs to."""
        return {"kind": "twin laser", "seed": str(self._cell.seed), "head": str(self.head)}

    def reset(self) -> None:
        """Reset the measured value, as the controller's reset does: the next reading has no value yet."""
        self._waiting = True

    async def read(self, *, timeout_s: float) -> DistanceReading:
        """One reading of the beam where the flange really is now."""
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        await self._round_trip(timeout_s)
        if self._waiting:
            self._waiting = False
            return DistanceReading(None, LaserStatus.NO_VALUE, time.monotonic(), self.head)
        status, distance = self._cell.laser_reading()
        return DistanceReading(distance, status, time.monotonic(), self.head)

    async def close(self) -> None:
        """Release the (simulated) port. Safe to call twice."""
        self._closed = True
