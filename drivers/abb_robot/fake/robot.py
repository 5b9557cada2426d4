"""The fake controller's robot: current pose, tool and work object frames, a running motion, the gripper.

Shared between the RAPID line server (asyncio) and the EGM thread, so every access takes the
lock. Frames: the model works on flange poses in the base frame; RAPID speaks TCP poses in the
current work object, ``T_wobj_tcp = inv(T_base_wobj) @ T_base_flange @ T_flange_tcp``.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from abb_robot import unit_quaternion
from abb_robot.fake.model import MovingRobotModel, RobotModel, Unreachable
from cellctl.ports import CartesianPose

IDENTITY = CartesianPose((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))


def interpolate(a: CartesianPose, b: CartesianPose, s: float) -> CartesianPose:
    """The pose a fraction ``s`` (0..1) of the way from a to b (straight line, slerp)."""
    pa, pb = np.asarray(a.position_mm), np.asarray(b.position_mm)
    p = pa + s * (pb - pa)
    return CartesianPose((float(p[0]), float(p[1]), float(p[2])), _slerp(a.quaternion_wxyz, b.quaternion_wxyz, s))


def _slerp(a: Sequence[float], b: Sequence[float], t: float) -> unit_quaternion.Quat:
    """Spherical interpolation from a (t = 0) to b (t = 1) along the shorter arc, w >= 0.

    The fake robot's path between two orientations, run every EGM cycle: on the quaternions
    themselves, which the ports carry (a round trip through rotation matrices would cost
    several times as much).
    """
    ua, ub = unit_quaternion.normalise(a), unit_quaternion.normalise(b)
    d = sum(x * y for x, y in zip(ua, ub))
    if d < 0:
        ub, d = (-ub[0], -ub[1], -ub[2], -ub[3]), -d
    if d > 0.9995:
        return unit_quaternion.normalise([x + t * (y - x) for x, y in zip(ua, ub)])
    theta = math.acos(d)
    s = math.sin(theta)
    wa, wb = math.sin((1 - t) * theta) / s, math.sin(t * theta) / s
    return unit_quaternion.normalise([wa * x + wb * y for x, y in zip(ua, ub)])


@dataclass
class Motion:
    """A point-to-point move in progress (flange poses)."""

    start: CartesianPose
    end: CartesianPose
    t0: float
    duration_s: float
    reported_at: Callable[[float], CartesianPose] | None = None  # the model's own path (a moving model), else smoothstep

    def pose_at(self, now: float) -> CartesianPose:
        if self.reported_at is not None:
            return self.reported_at(now)
        if self.duration_s <= 0:
            return self.end
        u = min(1.0, max(0.0, (now - self.t0) / self.duration_s))
        s = u * u * (3.0 - 2.0 * u)  # smooth start and stop
        return interpolate(self.start, self.end, s)


class FakeRobot:
    """The simulated arm as the controller sees it.

    Args:
        model: the physics (reach, timing, noise, joints).
        home: the flange pose at start.
        tools: tool name -> TCP in the flange frame (tframe). "tool0" is always present.
        wobjs: work object name -> work object frame in the base frame. "wobj0" is always present.
        time_scale: motion durations are multiplied by this (tests may speed moves up).
        clock: monotonic clock in seconds.
        gripper_hold: the gripper's vacuum output at start (True: on, holding).
        on_gripper: physics called with the new output whenever GRIP switches it (under the
            robot's lock, in the thread that serves the line protocol, as the model's calls are).
    """

    def __init__(
        self,
        model: RobotModel,
        home: CartesianPose,
        *,
        tools: dict[str, CartesianPose] | None = None,
        wobjs: dict[str, CartesianPose] | None = None,
        time_scale: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        gripper_hold: bool = False,
        on_gripper: Callable[[bool], None] | None = None,
    ) -> None:
        refusal = model.reachable(home)
        if refusal is not None:
            raise ValueError(f"home pose is not reachable: {refusal.reason}")
        if not (math.isfinite(time_scale) and time_scale > 0):
            raise ValueError(f"time_scale must be > 0, got {time_scale}")
        self.model = model
        self.lock = threading.RLock()
        self.tools = {"tool0": IDENTITY, **(tools or {})}
        self.wobjs = {"wobj0": IDENTITY, **(wobjs or {})}
        self.tool_name = "tool0"
        self.wobj_name = "wobj0"
        self.speed = (100.0, 30.0)
        self.zone_mm = 0.0
        self.motors_on = True
        self.time_scale = time_scale
        self.clock = clock
        self._flange = home
        self._motion: Motion | None = None
        self._gripper_hold = bool(gripper_hold)
        self._on_gripper = on_gripper

    # -- frames -------------------------------------------------------------------------------

    def _frames(self) -> tuple[CartesianPose, CartesianPose] | None:
        """Current (tool, wobj), or None when both are identity (tool0 in wobj0)."""
        with self.lock:
            tool, wobj = self.tools[self.tool_name], self.wobjs[self.wobj_name]
        if tool == IDENTITY and wobj == IDENTITY:
            return None
        return tool, wobj

    def tcp_to_flange(self, tcp_in_wobj: CartesianPose) -> CartesianPose:
        """The flange pose (base frame) that puts the current TCP at ``tcp_in_wobj``."""
        frames = self._frames()
        if frames is None:
            return tcp_in_wobj
        tool, wobj = frames
        return CartesianPose.from_matrix(wobj.to_matrix() @ tcp_in_wobj.to_matrix() @ np.linalg.inv(tool.to_matrix()))

    def flange_to_tcp(self, flange: CartesianPose) -> CartesianPose:
        """The current TCP in the current work object for a flange pose (base frame)."""
        frames = self._frames()
        if frames is None:
            return flange
        tool, wobj = frames
        return CartesianPose.from_matrix(np.linalg.inv(wobj.to_matrix()) @ flange.to_matrix() @ tool.to_matrix())

    # -- state --------------------------------------------------------------------------------

    def flange(self) -> CartesianPose:
        """Current flange pose (base frame), mid-motion if a move runs."""
        with self.lock:
            if self._motion is not None:
                return self._motion.pose_at(self.clock())
            return self._flange

    def tcp(self) -> CartesianPose:
        """Current TCP pose in the current work object (what CRobT reports)."""
        return self.flange_to_tcp(self.flange())

    def joints(self) -> tuple[float, ...]:
        return self.model.joints(self.flange())

    def set_flange(self, pose: CartesianPose) -> None:
        """Place the flange (used by the EGM loop, which moves the robot itself)."""
        with self.lock:
            self._flange = pose

    def jog(self, flange: CartesianPose) -> CartesianPose:
        """Someone jogs the robot on the teach pendant (or leads it by hand) to ``flange``.

        Any running move is ended first; the model executes the pose (the arm truly goes there,
        with its errors) and the controller reports the jogged pose from now on, as a real one
        reports wherever its arm was jogged to.
        """
        with self.lock:
            self._motion = None
            self.model.execute(flange)
            self._flange = flange
            return flange

    def settle_egm(self) -> CartesianPose:
        """An EGM session has ended: the arm truly stands where it left the flange (the model executes the
        pose, with its errors), as after a RAPID move."""
        with self.lock:
            self.model.execute(self._flange)
            return self._flange

    @property
    def moving(self) -> bool:
        with self.lock:
            return self._motion is not None

    # -- gripper ------------------------------------------------------------------------------

    @property
    def gripper_hold(self) -> bool:
        """The gripper's vacuum output: True on (holding), False off (released)."""
        with self.lock:
            return self._gripper_hold

    def set_gripper(self, hold: bool) -> None:
        """Switch the gripper's vacuum output (what the module's SetDO does).

        The physics callback is told first; if it raises, the output keeps its old value and
        the error propagates (the line server answers it as an I/O error).
        """
        with self.lock:
            if self._on_gripper is not None:
                self._on_gripper(hold)
            self._gripper_hold = hold

    # -- motions ------------------------------------------------------------------------------

    def check(self, tcp_target: CartesianPose) -> tuple[CartesianPose, Unreachable | None]:
        """The flange target for a TCP target, and the model's refusal if any."""
        flange_target = self.tcp_to_flange(tcp_target)
        return flange_target, self.model.reachable(flange_target)

    def begin_motion(self, flange_target: CartesianPose, linear: bool) -> Motion:
        """Start a move to a (reachable) flange target; returns it with its duration.

        A :class:`MovingRobotModel` moves by itself and the motion reports its path; any other
        model says where the move ends and the fake interpolates to it.
        """
        with self.lock:
            start = self.flange()
            if isinstance(self.model, MovingRobotModel):
                timed = self.model.begin(start, flange_target, self.speed[0], self.speed[1], self.time_scale)
                self._motion = Motion(start, flange_target, timed.t_start, timed.duration_s * self.time_scale, timed.reported_at)
                return self._motion
            end = self.model.execute(flange_target)
            duration = self.model.motion_time(start, flange_target, self.speed[0], self.speed[1], linear)
            self._motion = Motion(start, end, self.clock(), duration * self.time_scale)
            return self._motion

    def finish_motion(self, motion: Motion) -> None:
        with self.lock:
            if self._motion is motion:
                self._flange = motion.end
                self._motion = None

    def halt(self) -> bool:
        """Stop a running move where it is now; True if one was running."""
        with self.lock:
            if self._motion is None:
                return False
            if isinstance(self.model, MovingRobotModel):
                self._flange = self.model.halt()
            else:
                self._flange = self._motion.pose_at(self.clock())
            self._motion = None
            return True
