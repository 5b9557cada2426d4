"""In-process simulated devices: the robot and the laser of a :class:`SimCell` behind the ports.

They behave as the real devices do at the port: every call takes ``timeout_s`` and raises
DeviceTimeout when the (scaled) simulated time does not fit in it; a move the robot cannot reach
is refused with UnreachableTarget before anything moves; a stop ends a move early with
MotionInterrupted; the gripper is not switched while the robot moves (DeviceRejected); the robot
reports its belief, never the truth; a laser reading without a valid distance comes back as a status. Simulated durations are multiplied by the cell's ``time_scale``.

On the move (issue 19) both are computed from the arm's history on the twin's time line, never
polled: the robot's position feedback (:class:`cellctl.ports.PoseStream`) samples the reported
path every ``feedback_period_s`` and stamps each sample ``feedback_latency_s`` +- jitter late; the
laser's storage (:class:`cellctl.ports.StoringSensor`) reads the true flange ``storage_latency_s``
before each stored instant. Times are seconds on the cell's clock (``cell.timeline``).
"""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from cellctl.ports import (
    CartesianPose,
    DeviceDisconnected,
    DeviceError,
    DeviceRejected,
    DeviceTimeout,
    DistanceReading,
    LaserStatus,
    MotionInterrupted,
    MotionRequest,
    PoseSample,
    RobotState,
    StoredReadings,
    UnreachableTarget,
)
from cellctl.sim.arm import Motion, RobotBusy
from cellctl.sim.cell import SimCell
from cellctl.sim.robot import ReachError
from cellctl.sim.streams import rng_stream

# The stream of the feedback's phase on the controller's sample grid and of its stamps' jitter.
ROBOT_FEEDBACK = "robot.feedback"
# A feedback collection keeps its newest samples, at most this many (about 17 min at 4 ms).
MAX_STREAM_SAMPLES = 262_144
# The LK-G's storage: sampling 20..1000 us times 1..1000, at most 65535 readings.
STORAGE_CYCLE_S = (20e-6, 1.0)
MAX_STORAGE_COUNT = 65535


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
        self._latency_sim_s = latency_s
        self._closed = False

    def _check_open(self) -> None:
        if self._closed:
            raise DeviceDisconnected(self.name, self._closed_message)

    async def _round_trip(self, timeout_s: float) -> None:
        await self._take(self._latency_sim_s, timeout_s, "no answer", "device round trips")

    async def _take(self, simulated_s: float, timeout_s: float, what: str, spent_on: str) -> None:
        """Spend ``simulated_s`` of the cell's time on ``spent_on`` (scaled in real time), or DeviceTimeout
        saying ``what`` after ``timeout_s``."""
        if simulated_s * self._cell.time_scale > timeout_s:
            await asyncio.sleep(timeout_s)
            raise DeviceTimeout(self.name, f"{what} within {timeout_s:g} s")
        self._cell.timeline.waited(simulated_s, spent_on)
        await asyncio.sleep(simulated_s * self._cell.time_scale)

    async def ping(self, *, timeout_s: float) -> float:
        """A harmless round trip; returns its duration in seconds."""
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        t0 = time.monotonic()
        await self._round_trip(timeout_s)
        return time.monotonic() - t0


@dataclass(frozen=True)
class FeedbackFault:
    """A fault of the robot's feedback stream: a share of the samples lost, and the stream stopping
    ``stop_after_s`` (s, time line) after its start (None: it goes on)."""

    drop_fraction: float = 0.0
    stop_after_s: float | None = None


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
        self._feedback_rng = rng_stream(cell.seed, ROBOT_FEEDBACK)
        self.feedback_phase_s = float(self._feedback_rng.uniform(0.0, cell.config.robot.feedback_period_s))
        self._stream_from: float | None = None
        self.feedback_fault: FeedbackFault | None = None  # a test's fault on the feedback stream (None: healthy)
        self._fault_rng = rng_stream(cell.seed, ROBOT_FEEDBACK + ".fault")

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

    async def start_stream(self, *, timeout_s: float) -> None:
        """Start collecting the position feedback (the previous collection is dropped)."""
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        await self._round_trip(timeout_s)
        self._stream_from = self._cell.timeline.now()

    async def stop_stream(self, *, timeout_s: float) -> tuple[PoseSample, ...]:
        """Stop collecting; the samples stamped since :meth:`start_stream`, in time order (DeviceRejected if none)."""
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        if self._stream_from is None:
            raise DeviceRejected(self.name, "no feedback stream was started; call start_stream first")
        await self._round_trip(timeout_s)
        t_from, self._stream_from = self._stream_from, None
        t_to = self._cell.timeline.now()
        with self._cell.timeline.unclocked():  # the controller streamed these while the robot moved
            return await asyncio.to_thread(self._feedback, t_from, t_to)  # ~0.3 s of CPU per sweep: off the loop

    def stream_unavailable(self) -> str | None:
        """None: the twin's robot always streams its feedback."""
        return None

    def latest(self) -> PoseSample | None:
        """The newest feedback sample since :meth:`start_stream` (its stamp without jitter), or None."""
        if self._stream_from is None:
            return None
        c = self._cell.config.robot
        t_to = self._cell.timeline.now()
        if self.feedback_fault is not None and self.feedback_fault.stop_after_s is not None:
            t_to = min(t_to, self._stream_from + self.feedback_fault.stop_after_s)
        k = math.floor((t_to - c.feedback_latency_s - self.feedback_phase_s) / c.feedback_period_s)
        instant = self.feedback_phase_s + k * c.feedback_period_s
        if instant + c.feedback_latency_s < self._stream_from:
            return None
        try:
            pose = self._arm.belief_at_line(instant)
        except LookupError:
            return None
        return PoseSample(instant + c.feedback_latency_s, CartesianPose.from_matrix(pose))

    def _feedback(self, t_from: float, t_to: float) -> tuple[PoseSample, ...]:
        """The samples whose stamps fall in [t_from, t_to] (s, time line): the reported pose at each true instant."""
        c = self._cell.config.robot
        period, late, jitter = c.feedback_period_s, c.feedback_latency_s, c.feedback_jitter_s
        fault = self.feedback_fault
        if fault is not None and fault.stop_after_s is not None:
            t_to = min(t_to, t_from + fault.stop_after_s)
        first = math.ceil((t_from - late - jitter - self.feedback_phase_s) / period)
        last = math.floor((t_to - late + jitter - self.feedback_phase_s) / period)
        instants = self.feedback_phase_s + np.arange(first, max(last + 1, first)) * period
        stamps = instants + late + self._feedback_rng.uniform(-jitter, jitter, size=instants.size)
        keep = (stamps >= t_from) & (stamps <= t_to)
        if fault is not None and fault.drop_fraction > 0.0:
            keep &= self._fault_rng.random(stamps.size) >= fault.drop_fraction
        instants, stamps = instants[keep][-MAX_STREAM_SAMPLES:], stamps[keep][-MAX_STREAM_SAMPLES:]
        try:
            poses = [self._arm.belief_at_line(float(t)) for t in instants]
        except LookupError as err:
            raise DeviceError(self.name, f"feedback lost: {err}") from None
        return tuple(PoseSample(float(t), CartesianPose.from_matrix(T)) for t, T in zip(stamps, poses, strict=True))

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
        settle_s = self._cell.config.robot.gripper_settle_s
        self._cell.timeline.waited(settle_s, "gripper")
        await asyncio.sleep(settle_s * self._cell.time_scale)

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
        self._storage: tuple[float, float, int] | None = None

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
        with self._cell.timeline.unclocked():
            status, distance = self._cell.laser_reading()
        return DistanceReading(distance, status, time.monotonic(), self.head)

    async def start_storage(self, *, cycle_s: float, count: int, timeout_s: float) -> float:
        """Clear the storage, store a reading every ``cycle_s`` (at most ``count``); returns ``started_s`` (s).

        Refused (DeviceRejected) for a cycle outside 20 us .. 1 s or a count outside 1..65535.
        """
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        number = isinstance(cycle_s, (int, float)) and not isinstance(cycle_s, bool)
        if not number or not math.isfinite(cycle_s):
            raise ValueError(f"{self.name}: cycle_s must be a finite number of seconds, got {cycle_s!r}")
        if not isinstance(count, int) or isinstance(count, bool):
            raise TypeError(f"{self.name}: count must be a whole number, got {count!r}")
        low, high = STORAGE_CYCLE_S
        if not (low * (1.0 - 1e-9) <= cycle_s <= high * (1.0 + 1e-9)):
            raise DeviceRejected(
                self.name,
                f"storage cycle {cycle_s:g} s refused: the LK-G stores every 20 us .. 1 s "
                "(its sampling period 20..1000 us times 1, 2, 5 .. 1000)",
            )
        if not (1 <= count <= MAX_STORAGE_COUNT):
            limit = f"the LK-G stores 1..{MAX_STORAGE_COUNT} readings"
            raise DeviceRejected(self.name, f"storage count {count} refused: {limit}")
        await self._round_trip(timeout_s)
        started_s = self._cell.timeline.now()
        self._storage = (started_s, float(cycle_s), count)
        return started_s

    async def stop_storage(self, *, timeout_s: float) -> StoredReadings:
        """Stop storing and read out the readings stored since :meth:`start_storage` (DeviceRejected without one).

        Reading k is the beam at the true flange pose ``storage_latency_s`` before ``started_s + k * cycle_s``;
        reading them out takes ``readout_s_per_reading`` each.
        """
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        if self._storage is None:
            raise DeviceRejected(self.name, "no storage was started; call start_storage first")
        await self._round_trip(timeout_s)
        (started_s, cycle_s, count), self._storage = self._storage, None
        stored = min(count, max(math.floor((self._cell.timeline.now() - started_s) / cycle_s) + 1, 0))
        readout_s = stored * self._cell.config.laser.readout_s_per_reading  # the readings on the serial line
        await self._take(readout_s, timeout_s, f"{stored} stored readings not read out", "laser read-out")
        try:  # thousands of ray casts: the twin's physics, off the event loop and off the cell's clock
            with self._cell.timeline.unclocked():
                distances = await asyncio.to_thread(self._stored_distances, started_s, cycle_s, stored)
        except LookupError as err:
            raise DeviceError(self.name, f"storage lost: {err}") from None
        return StoredReadings(started_s, cycle_s, distances)

    def _stored_distances(self, started_s: float, cycle_s: float, stored: int) -> tuple[float | None, ...]:
        latency_s = self._cell.config.laser.storage_latency_s
        return tuple(
            self._cell.laser_reading(self._cell.arm.true_at_line(started_s + k * cycle_s - latency_s))[1] for k in range(stored)
        )

    async def close(self) -> None:
        """Release the (simulated) port. Safe to call twice."""
        self._closed = True
