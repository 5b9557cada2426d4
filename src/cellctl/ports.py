"""Device interfaces (ports) and the value and error types they share.

The core of cellctl knows devices only through these protocols; drivers in ``drivers/`` implement
them and import nothing else from the core. Every call is a coroutine with an explicit timeout:
a device that does not answer in time raises :class:`DeviceTimeout`, never hangs.

Units: millimetres and radians; poses are flange poses ``T_B_H`` (tool0 in the robot base frame).
On the wire to a robot a pose travels as :class:`CartesianPose` (position in mm, quaternion
w, x, y, z as ABB orders it).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.pose import check_pose, make_pose
from cellctl.geometry.rotation import matrix_to_quat, quat_to_matrix

# ---------------------------------------------------------------------------------------------
# Errors


class DeviceError(Exception):
    """A device failed to do what was asked. ``device`` names it in the cell's words."""

    def __init__(self, device: str, message: str) -> None:
        super().__init__(f"{device}: {message}")
        self.device = device
        self.message = message


class DeviceTimeout(DeviceError):
    """No (complete) answer within the call's timeout."""


class DeviceBusy(DeviceTimeout):
    """The link was taken by another call for the whole timeout (e.g. a storage read-out): nothing was asked."""


class DeviceDisconnected(DeviceError):
    """The link to the device is down (port vanished, socket closed); the driver may reconnect."""


class DeviceProtocolError(DeviceError):
    """The device answered with something the protocol does not allow (garbage, wrong echo)."""


class DeviceRejected(DeviceError):
    """The device understood the request and refused it with an error code of its own."""

    def __init__(self, device: str, message: str, code: str | None = None) -> None:
        super().__init__(device, message if code is None else f"{message} (code {code})")
        self.code = code


class MeasurementUnavailable(DeviceError):
    """The sensor answered but has no valid measurement (over range, no value yet)."""

    def __init__(self, device: str, message: str, status: "LaserStatus") -> None:
        super().__init__(device, message)
        self.status = status


class UnreachableTarget(DeviceRejected):
    """The robot refused a target outside its reach or joint limits."""


class MotionInterrupted(DeviceError):
    """A motion was stopped before it reached its target (stop request, fault, lost link)."""


@runtime_checkable
class Device(Protocol):
    """What every device port has: a harmless call for the watchdog, and a close."""

    async def ping(self, *, timeout_s: float) -> float:
        """A harmless round trip for the watchdog; returns its duration in seconds."""
        ...

    async def close(self) -> None:
        """Release the device (port, socket or camera). Safe to call twice."""
        ...


# ---------------------------------------------------------------------------------------------
# Displacement sensor (the LK-G laser)


class LaserStatus(enum.Enum):
    """What a laser displacement reading says about its value."""

    OK = "ok"
    OVER_RANGE_NEAR = "over_range_near"  # LK-G: -FFFFFFF, the target is nearer than the range
    OVER_RANGE_FAR = "over_range_far"  # LK-G: +FFFFFFF, beyond the range or no return
    NO_VALUE = "no_value"  # LK-G: XXXXXXXX, no measurement yet (e.g. after a reset)


@dataclass(frozen=True)
class DistanceReading:
    """One laser displacement reading.

    Attributes:
        distance_mm: the distance along the laser from its origin r (eq. 1), or None when the
            status is not OK.
        status: what the sensor reported.
        timestamp_s: monotonic time (``time.monotonic()``) when the reply arrived.
        head: the sensor head (output) number, 1-based.
    """

    distance_mm: float | None
    status: LaserStatus
    timestamp_s: float
    head: int = 1

    def __post_init__(self) -> None:
        if (self.status is LaserStatus.OK) != (self.distance_mm is not None):
            raise ValueError("distance_mm must be set exactly when status is OK")


@runtime_checkable
class DisplacementSensor(Device, Protocol):
    """A laser displacement sensor measuring along a fixed ray of the flange frame."""

    async def read(self, *, timeout_s: float) -> DistanceReading:
        """One reading. Over range and no value come back as a status, not as an exception."""
        ...


@dataclass(frozen=True)
class StoredReadings:
    """Readings a sensor stored on its own at a fixed cycle while the robot moved (LK-G data storage).

    The k-th reading stands for the instant ``started_s + k * cycle_s`` on the cell's clock (the
    clock of :class:`cellctl.cell.cycle_values.CellDevices`); the sensor's own delay on top of that is the
    latency the cell estimates. ``distances_mm`` is None where a reading had no valid distance.
    """

    started_s: float
    cycle_s: float
    distances_mm: tuple[float | None, ...]


@runtime_checkable
class StoringSensor(Protocol):
    """A displacement sensor that stores readings at a fixed cycle by itself (LK-G: AQ, AS, AP, AO)."""

    async def start_storage(self, *, cycle_s: float, count: int, timeout_s: float) -> float:
        """Clear the storage and store a reading every ``cycle_s`` (at most ``count``); returns ``started_s``."""
        ...

    async def stop_storage(self, *, timeout_s: float) -> StoredReadings:
        """Stop storing and read out what was stored."""
        ...


# ---------------------------------------------------------------------------------------------
# Camera


@dataclass(frozen=True)
class Frame:
    """One image from the camera.

    Attributes:
        image: (height, width) uint8 grey values, row 0 at the top (v down, u right).
        timestamp_s: monotonic time the frame arrived on the host.
        frame_id: the camera's frame counter (or the driver's, if the camera has none).
        device_timestamp_ns: the camera's own timestamp, if it provides one.
        exposure_us: exposure time in effect, if known.
        gain_db: gain in effect, if known.
    """

    image: NDArray[np.uint8]
    timestamp_s: float
    frame_id: int
    device_timestamp_ns: int | None = None
    exposure_us: float | None = None
    gain_db: float | None = None

    def __post_init__(self) -> None:
        if self.image.ndim != 2 or self.image.dtype != np.uint8:
            raise ValueError(f"frame image must be 2-D uint8, got {self.image.dtype} {self.image.shape}")


@runtime_checkable
class Camera(Device, Protocol):
    """A monochrome industrial camera on the robot's fixture."""

    async def grab(self, *, timeout_s: float) -> Frame:
        """Trigger (if in trigger mode) and return one new frame."""
        ...


# ---------------------------------------------------------------------------------------------
# Robot


@dataclass(frozen=True)
class CartesianPose:
    """A flange pose as robots speak it: position (mm) and unit quaternion (w, x, y, z)."""

    position_mm: tuple[float, float, float]
    quaternion_wxyz: tuple[float, float, float, float]

    def __post_init__(self) -> None:
        if len(self.position_mm) != 3 or not np.all(np.isfinite(self.position_mm)):
            raise ValueError(f"position_mm must be 3 finite numbers, got {self.position_mm!r}")
        q = np.asarray(self.quaternion_wxyz, dtype=float)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1.0) > 1e-6:
            raise ValueError(f"quaternion_wxyz must be a unit quaternion (w, x, y, z), got {self.quaternion_wxyz!r}")

    @classmethod
    def from_matrix(cls, T: NDArray[np.float64]) -> "CartesianPose":
        """From a 4x4 pose (checked to be rigid)."""
        M = check_pose(T, "pose")
        q = matrix_to_quat(M[:3, :3])
        return cls(
            (float(M[0, 3]), float(M[1, 3]), float(M[2, 3])),
            (float(q[0]), float(q[1]), float(q[2]), float(q[3])),
        )

    def to_matrix(self) -> NDArray[np.float64]:
        """The 4x4 pose."""
        return make_pose(quat_to_matrix(self.quaternion_wxyz), self.position_mm)


MotionKind = Literal["linear", "joint"]


@dataclass(frozen=True)
class MotionRequest:
    """One point-to-point move of the flange to ``target`` (T_B_H), ending at a fine point.

    Attributes:
        target: the flange pose to reach.
        kind: "linear" (MoveL, straight TCP path) or "joint" (MoveJ).
        speed_mm_s: TCP speed.
        speed_deg_s: reorientation speed.
    """

    target: CartesianPose
    kind: MotionKind = "linear"
    speed_mm_s: float = 100.0
    speed_deg_s: float = 30.0

    def __post_init__(self) -> None:
        if self.kind not in ("linear", "joint"):
            raise ValueError(f"kind must be 'linear' or 'joint', got {self.kind!r}")
        if not (0.0 < self.speed_mm_s <= 7000.0):
            raise ValueError(f"speed_mm_s must be in (0, 7000], got {self.speed_mm_s}")
        if not (0.0 < self.speed_deg_s <= 1000.0):
            raise ValueError(f"speed_deg_s must be in (0, 1000], got {self.speed_deg_s}")


@dataclass(frozen=True)
class RobotState:
    """What the robot reports about itself (informational; safety is not ours)."""

    motors_on: bool
    program_running: bool
    moving: bool
    joints_rad: tuple[float, ...] = field(default=())


@runtime_checkable
class Robot(Device, Protocol):
    """A six-axis robot moving its flange (tool0) in its base frame (wobj0)."""

    async def move(self, request: MotionRequest, *, timeout_s: float) -> CartesianPose:
        """Move to the target and wait until it is reached; returns the pose read back after it.

        Raises UnreachableTarget if the controller refuses the target, MotionInterrupted if the
        motion ends early, DeviceTimeout if it is not done in ``timeout_s``.
        """
        ...

    async def read_pose(self, *, timeout_s: float) -> CartesianPose:
        """The current flange pose T_B_H."""
        ...

    async def state(self, *, timeout_s: float) -> RobotState:
        """Motors, program and motion state, and the joint angles."""
        ...

    async def stop(self, *, timeout_s: float) -> None:
        """Request the current motion to stop (a normal stop, not a safety function)."""
        ...

    async def set_gripper(self, hold: bool, *, timeout_s: float) -> None:
        """Switch the gripper's vacuum on (``hold``: hold the glass) or off (release it).

        Returns once the gripper has switched and its vacuum has settled, so the glass is held, or
        free of the gripper, when it returns. Refused while the robot moves (DeviceRejected; the
        gripper keeps its state): a glass is never released mid-motion. Raises DeviceTimeout if it
        is not confirmed within ``timeout_s`` (the gripper may or may not have switched; switching
        again to the same state is harmless), DeviceError if the gripper cannot be switched.
        """
        ...


@dataclass(frozen=True)
class PoseSample:
    """One sample of the robot's position feedback: the flange pose and its instant on the cell's clock (s)."""

    t_s: float
    pose: CartesianPose


@runtime_checkable
class PoseStream(Protocol):
    """The robot's position feedback while it moves (ABB: the EGM feedback stream, every 4 ms)."""

    def stream_unavailable(self) -> str | None:
        """Why this robot cannot stream its pose (its feedback channel is not configured), or None."""
        ...

    async def start_stream(self, *, timeout_s: float) -> None:
        """Start collecting feedback samples (the previous collection is dropped)."""
        ...

    async def stop_stream(self, *, timeout_s: float) -> tuple[PoseSample, ...]:
        """Stop collecting; the samples since :meth:`start_stream`, in time order."""
        ...

    def latest(self) -> PoseSample | None:
        """The newest sample received since :meth:`start_stream` (None before the first): how fresh the stream is."""
        ...


@runtime_checkable
class Identified(Protocol):
    """A device that can say what it is (model, serial number, firmware, address) without a call.

    Optional beside the device's port: commissioning datasets record it, so a calibration can be
    traced to the very robot, camera and laser it was made with.
    """

    def identity(self) -> dict[str, str]:
        """What the device said about itself when it was opened (empty values when unknown)."""
        ...


@runtime_checkable
class FineCorrection(Protocol):
    """Streaming fine correction of the flange pose (ABB EGM), for small moves near a target."""

    async def correct_to(
        self, target: CartesianPose, *, tolerance_mm: float, tolerance_rad: float, timeout_s: float
    ) -> CartesianPose:
        """Stream ``target`` until the robot's reported pose converges within the tolerances."""
        ...
