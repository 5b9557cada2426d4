"""The fake controller's physics: what a target reaches, how long a move takes, what it refuses.

The fake speaks the wire protocols; how its robot moves comes from a :class:`RobotModel`, so the
composition root can plug in the twin's robot (with its own noise, timing and kinematics) while
the driver package stays free of the twin. Poses are flange poses (tool0) in the robot base frame
(wobj0), in mm, quaternions w, x, y, z; joint angles in radians.

:class:`SimpleArmModel` is the default: an IRB 7600-325/3.1-like arm with the link lengths and
axis limits noted in the project's ABB reference notes, an elbow-up spherical-wrist solution, a
reach sphere around the shoulder, trapezoidal move times and Gaussian repeatability noise. Its
joint angles follow ABB's directions (axis 2 forward from vertical, axis 3 zero with the forearm
perpendicular to the upper arm) but ignore the forearm's 165 mm offset, so they are close to, not
equal to, what a real IRB 7600 reports.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

import numpy as np

from abb_robot import unit_quaternion
from cellctl.ports import CartesianPose

RefusalKind = Literal["reach", "joint_limit"]


@dataclass(frozen=True)
class Unreachable:
    """Why a target is refused: outside the reach, or beyond an axis limit."""

    kind: RefusalKind
    reason: str


@runtime_checkable
class RobotModel(Protocol):
    """The physics the fake controller asks for. All poses are flange poses in the base frame."""

    def reachable(self, target: CartesianPose) -> Unreachable | None:
        """None if the robot can reach ``target``; otherwise why not."""
        ...

    def motion_time(
        self, start: CartesianPose, target: CartesianPose, speed_mm_s: float, speed_deg_s: float, linear: bool
    ) -> float:
        """Seconds a point-to-point move from ``start`` to ``target`` takes (fine point at the end)."""
        ...

    def execute(self, target: CartesianPose) -> CartesianPose:
        """The pose the robot actually reaches when sent to ``target`` (repeatability noise)."""
        ...

    def joints(self, pose: CartesianPose) -> tuple[float, ...]:
        """The six joint angles (rad) at ``pose`` (which is reachable)."""
        ...


@dataclass(frozen=True)
class TimedMove:
    """A move a :class:`MovingRobotModel` has begun: its duration and the reported pose along it."""

    duration_s: float  # seconds of the move on the model's time (settling included)
    t_start: float  # when it began, on the fake's clock
    reported_at: Callable[[float], CartesianPose]  # the flange pose the controller reports at a clock instant


@runtime_checkable
class MovingRobotModel(RobotModel, Protocol):
    """A model whose robot moves in time itself (the twin's arm): the fake reports its path, not its own.

    Without it the fake interpolates a move by itself and the model only says where it ends.
    """

    def begin(
        self, start: CartesianPose, target: CartesianPose, speed_mm_s: float, speed_deg_s: float, time_scale: float
    ) -> TimedMove:
        """Start moving from ``start`` to ``target`` (reachable) now, ``time_scale`` real seconds per model second."""
        ...

    def halt(self) -> CartesianPose:
        """Stop the running move where the robot is; the reported pose there."""
        ...


@dataclass(frozen=True)
class ArmGeometry:
    """Link lengths (mm) in the OPW naming of the reference notes (IRB 7600-325/3.1 defaults)."""

    a1: float = 410.0  # axis 1 to axis 2, horizontal
    c1: float = 780.0  # base to axis 2, vertical
    c2: float = 1075.0  # upper arm
    a2: float = -165.0  # forearm offset
    c3: float = 1556.0  # forearm to the wrist centre
    c4: float = 250.0  # wrist centre to flange

    @property
    def forearm(self) -> float:
        """Elbow to wrist centre, a straight link in this model."""
        return math.hypot(self.a2, self.c3)


# Axis limits (deg) of the IRB 7600-325/3.1 in the reference notes (to be confirmed from ABB's
# product specification before relying on them).
DEFAULT_LIMITS_DEG: tuple[tuple[float, float], ...] = (
    (-180.0, 180.0),
    (-60.0, 85.0),
    (-180.0, 60.0),
    (-300.0, 300.0),
    (-100.0, 100.0),
    (-360.0, 360.0),
)


class SimpleArmModel:
    """Default :class:`RobotModel`: a six-axis arm with a spherical wrist and a reach sphere.

    Args:
        geometry: link lengths.
        limits_deg: axis limits (min, max) in degrees for axes 1..6.
        repeatability_mm: one-sigma position noise per axis added by :meth:`execute`.
        repeatability_rad: one-sigma orientation noise (rotation vector per axis).
        max_speed_mm_s: the model never moves the TCP faster, whatever is asked.
        acceleration_mm_s2: linear acceleration of the trapezoidal profile.
        angular_acceleration_deg_s2: angular acceleration of the trapezoidal profile.
        min_reach_mm: the wrist centre must stay this far from the shoulder (inner dead zone).
        seed: seed of the noise generator.
    """

    def __init__(
        self,
        *,
        geometry: ArmGeometry = ArmGeometry(),
        limits_deg: tuple[tuple[float, float], ...] = DEFAULT_LIMITS_DEG,
        repeatability_mm: float = 0.03,
        repeatability_rad: float = 5e-5,
        max_speed_mm_s: float = 2000.0,
        acceleration_mm_s2: float = 4000.0,
        angular_acceleration_deg_s2: float = 400.0,
        min_reach_mm: float = 600.0,
        seed: int = 0,
    ) -> None:
        if len(limits_deg) != 6 or any(lo >= hi for lo, hi in limits_deg):
            raise ValueError("limits_deg must be six (min, max) pairs with min < max")
        for name, value in (
            ("repeatability_mm", repeatability_mm),
            ("repeatability_rad", repeatability_rad),
        ):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")
        for name, value in (
            ("max_speed_mm_s", max_speed_mm_s),
            ("acceleration_mm_s2", acceleration_mm_s2),
            ("angular_acceleration_deg_s2", angular_acceleration_deg_s2),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value}")
        self.geometry = geometry
        self.limits_rad = tuple((math.radians(lo), math.radians(hi)) for lo, hi in limits_deg)
        self.repeatability_mm = repeatability_mm
        self.repeatability_rad = repeatability_rad
        self.max_speed_mm_s = max_speed_mm_s
        self.acceleration_mm_s2 = acceleration_mm_s2
        self.angular_acceleration_deg_s2 = angular_acceleration_deg_s2
        self.min_reach_mm = min_reach_mm
        self._rng = np.random.default_rng(seed)

    # -- kinematics ---------------------------------------------------------------------------

    @property
    def reach_mm(self) -> float:
        """Radius of the reach sphere of the wrist centre around the shoulder (axis 2)."""
        return self.geometry.c2 + self.geometry.forearm

    def _solve(self, pose: CartesianPose) -> tuple[tuple[float, ...] | None, Unreachable | None]:
        g = self.geometry
        R = pose.to_matrix()[:3, :3]
        p = np.asarray(pose.position_mm, dtype=float)
        w = p - g.c4 * R[:, 2]
        j1 = math.atan2(w[1], w[0])
        r = math.hypot(w[0], w[1]) - g.a1
        h = w[2] - g.c1
        d = math.hypot(r, h)
        L3 = g.forearm
        if d > g.c2 + L3 - 1e-6:
            return None, Unreachable("reach", f"wrist centre {d:.0f} mm from shoulder > reach sphere {g.c2 + L3:.0f} mm")
        if d < max(self.min_reach_mm, abs(g.c2 - L3)):
            return None, Unreachable(
                "reach", f"wrist centre {d:.0f} mm from shoulder < dead zone {max(self.min_reach_mm, abs(g.c2 - L3)):.0f} mm"
            )
        phi = math.atan2(r, h)  # shoulder-to-wrist line from vertical, forward positive
        beta = math.acos(max(-1.0, min(1.0, (g.c2**2 + d**2 - L3**2) / (2 * g.c2 * d))))
        j2 = phi - beta  # elbow up
        er, eh = g.c2 * math.sin(j2), g.c2 * math.cos(j2)
        psi = math.atan2(r - er, h - eh)  # forearm from vertical
        j3 = psi - j2 - math.pi / 2
        R_f = self._forearm_frame(j1, psi)
        W = R_f.T @ R
        j5 = math.acos(max(-1.0, min(1.0, W[2, 2])))
        if j5 < 1e-9:
            j4 = 0.0
            j6 = math.atan2(W[1, 0], W[0, 0])
        else:
            j4 = math.atan2(W[1, 2], W[0, 2])
            j6 = math.atan2(W[2, 1], -W[2, 0])
        if abs(j4) > math.pi / 2:  # same rotation with the wrist bent the other way: keep axis 4 near 0
            j4 -= math.copysign(math.pi, j4)
            j5 = -j5
            j6 -= math.copysign(math.pi, j6)
        joints = (j1, j2, _wrap(j3), j4, j5, _wrap(j6))
        for axis, (value, (lo, hi)) in enumerate(zip(joints, self.limits_rad), start=1):
            if not (lo - 1e-9 <= value <= hi + 1e-9):
                return None, Unreachable(
                    "joint_limit",
                    f"axis {axis} at {math.degrees(value):.1f} deg, limits {math.degrees(lo):.0f}..{math.degrees(hi):.0f}",
                )
        return joints, None

    @staticmethod
    def _forearm_frame(j1: float, psi: float) -> np.ndarray:
        """Rotation whose z axis runs along the forearm and whose y axis is the elbow axis."""
        c1, s1 = math.cos(j1), math.sin(j1)
        z = np.array([math.sin(psi) * c1, math.sin(psi) * s1, math.cos(psi)])
        y = np.array([-s1, c1, 0.0])
        x = np.cross(y, z)
        return np.column_stack([x, y, z])

    def pose_from_joints(self, joints: tuple[float, ...]) -> CartesianPose:
        """Forward kinematics of this model (the inverse of :meth:`joints`)."""
        g = self.geometry
        j1, j2, j3, j4, j5, j6 = joints
        c1, s1 = math.cos(j1), math.sin(j1)
        psi = j2 + j3 + math.pi / 2
        r = g.a1 + g.c2 * math.sin(j2) + g.forearm * math.sin(psi)
        h = g.c1 + g.c2 * math.cos(j2) + g.forearm * math.cos(psi)
        w = np.array([r * c1, r * s1, h])
        R = self._forearm_frame(j1, psi) @ rot_z(j4) @ rot_y(j5) @ rot_z(j6)
        return _pose(w + g.c4 * R[:, 2], R)

    # -- RobotModel ---------------------------------------------------------------------------

    def reachable(self, target: CartesianPose) -> Unreachable | None:
        return self._solve(target)[1]

    def joints(self, pose: CartesianPose) -> tuple[float, ...]:
        joints, refusal = self._solve(pose)
        if joints is None:
            assert refusal is not None
            raise ValueError(f"pose is not reachable: {refusal.reason}")
        return joints

    def motion_time(
        self, start: CartesianPose, target: CartesianPose, speed_mm_s: float, speed_deg_s: float, linear: bool
    ) -> float:
        dist = float(np.linalg.norm(np.subtract(target.position_mm, start.position_mm)))
        angle_deg = math.degrees(unit_quaternion.angle_between(start.quaternion_wxyz, target.quaternion_wxyz))
        v = min(speed_mm_s, self.max_speed_mm_s)
        t_lin = _trapezoid(dist, v, self.acceleration_mm_s2)
        t_rot = _trapezoid(angle_deg, speed_deg_s, self.angular_acceleration_deg_s2)
        t = max(t_lin, t_rot)
        return t if linear else 0.9 * t

    def execute(self, target: CartesianPose) -> CartesianPose:
        dp = self._rng.normal(0.0, self.repeatability_mm, 3) if self.repeatability_mm > 0 else np.zeros(3)
        dr = self._rng.normal(0.0, self.repeatability_rad, 3) if self.repeatability_rad > 0 else np.zeros(3)
        p = np.asarray(target.position_mm, dtype=float) + dp
        return _pose(p, rot_vector(dr) @ target.to_matrix()[:3, :3])


def _trapezoid(distance: float, v_max: float, accel: float) -> float:
    """Duration of a rest-to-rest move over ``distance`` with speed and acceleration limits."""
    if distance <= 0:
        return 0.0
    if distance >= v_max * v_max / accel:
        return distance / v_max + v_max / accel
    return 2.0 * math.sqrt(distance / accel)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _pose(p: np.ndarray, R: np.ndarray) -> CartesianPose:
    """The pose at position ``p`` (mm) with rotation ``R`` (through the ports' conversion)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return CartesianPose.from_matrix(T)


def rot_x(a: float) -> np.ndarray:
    """Rotation by ``a`` rad about x."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Rotation by ``a`` rad about y."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation by ``a`` rad about z."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_vector(v: np.ndarray) -> np.ndarray:
    """Rotation of a rotation vector (axis times angle, rad), Rodrigues' formula."""
    angle = float(np.linalg.norm(v))
    if angle < 1e-15:
        return np.eye(3)
    k = np.asarray(v, dtype=float) / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)
