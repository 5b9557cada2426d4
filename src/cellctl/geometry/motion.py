"""How long a point-to-point move takes, and where the flange is along the way.

A robot controller moves the flange along a straight line while turning it about a fixed axis
(MoveL), translation and rotation synchronised, each with a trapezoidal speed profile (accelerate,
cruise, decelerate; a triangle if the move is too short to reach cruise speed). The slower of
the two sets the duration; the other is stretched to it, so both finish together. A fine point
adds a settling time at the end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from cellctl.geometry.pose import Pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix, matrix_to_axis_angle


@dataclass(frozen=True)
class TrapezoidProfile:
    """A rest-to-rest move over ``distance`` with speed limit ``speed`` and acceleration ``acceleration``.

    Units are any consistent pair (mm, mm/s, mm/s^2 or rad, rad/s, rad/s^2).
    """

    distance: float
    speed: float
    acceleration: float

    def __post_init__(self) -> None:
        if not np.isfinite(self.distance) or self.distance < 0:
            raise ValueError(f"distance must be a finite non-negative number, got {self.distance}")
        if not np.isfinite(self.speed) or self.speed <= 0:
            raise ValueError(f"speed must be a positive number, got {self.speed}")
        if not np.isfinite(self.acceleration) or self.acceleration <= 0:
            raise ValueError(f"acceleration must be a positive number, got {self.acceleration}")

    @property
    def peak_speed(self) -> float:
        """The speed reached: the limit, or less if the move ends before reaching it."""
        return float(min(self.speed, np.sqrt(self.distance * self.acceleration)))

    @property
    def duration(self) -> float:
        """Time from rest to rest (s)."""
        if self.distance == 0.0:
            return 0.0
        v = self.peak_speed
        return float(self.distance / v + v / self.acceleration)

    def travelled(self, t: float) -> float:
        """Distance covered after ``t`` seconds (clamped to [0, distance])."""
        if self.distance == 0.0 or t <= 0.0:
            return 0.0
        T = self.duration
        if t >= T:
            return self.distance
        v, a = self.peak_speed, self.acceleration
        t_acc = v / a
        if t < t_acc:
            return 0.5 * a * t * t
        if t <= T - t_acc:
            return 0.5 * v * t_acc + v * (t - t_acc)
        return self.distance - 0.5 * a * (T - t) ** 2


@dataclass(frozen=True)
class PathTiming:
    """The synchronised timing of one move: translation and rotation finish together.

    Attributes:
        translation: the profile of the straight-line translation (mm).
        rotation: the profile of the rotation about the fixed axis (rad).
        settle_s: settling time at the fine point, after the path ends.
    """

    translation: TrapezoidProfile
    rotation: TrapezoidProfile
    settle_s: float

    @property
    def path_s(self) -> float:
        """Time on the path (s), without settling."""
        return max(self.translation.duration, self.rotation.duration)

    @property
    def duration_s(self) -> float:
        """Total time of the move including the settling time (s)."""
        return self.path_s + self.settle_s

    def fraction(self, t: float) -> float:
        """How far along the path (0 to 1) the flange is ``t`` seconds after the start."""
        T = self.path_s
        if T == 0.0 or t >= T:
            return 1.0
        if t <= 0.0:
            return 0.0
        leader = self.translation if self.translation.duration >= self.rotation.duration else self.rotation
        return leader.travelled(t) / leader.distance


def interpolate_pose(T_a: ArrayLike, T_b: ArrayLike, s: float) -> Pose:
    """The pose a fraction ``s`` of the way from ``T_a`` to ``T_b`` (straight line, fixed-axis turn)."""
    A = np.asarray(T_a, dtype=float)
    B = np.asarray(T_b, dtype=float)
    if s <= 0.0:
        return A.copy()
    if s >= 1.0:
        return B.copy()
    rotvec = matrix_to_axis_angle(A[:3, :3].T @ B[:3, :3])
    R = A[:3, :3] @ axis_angle_to_matrix(s * rotvec)
    return make_pose(R, (1.0 - s) * A[:3, 3] + s * B[:3, 3])


def path_timing(
    T_from: ArrayLike,
    T_to: ArrayLike,
    *,
    speed_mm_s: float,
    acceleration_mm_s2: float,
    speed_rad_s: float,
    acceleration_rad_s2: float,
    settle_s: float,
) -> PathTiming:
    """The timing of a linear move from ``T_from`` to ``T_to`` with the given limits."""
    A = np.asarray(T_from, dtype=float)
    B = np.asarray(T_to, dtype=float)
    distance = float(np.linalg.norm(B[:3, 3] - A[:3, 3]))
    angle = float(np.linalg.norm(matrix_to_axis_angle(A[:3, :3].T @ B[:3, :3])))
    if not np.isfinite(settle_s) or settle_s < 0:
        raise ValueError(f"settle_s must be a finite non-negative number, got {settle_s}")
    return PathTiming(
        TrapezoidProfile(distance, speed_mm_s, acceleration_mm_s2),
        TrapezoidProfile(angle, speed_rad_s, acceleration_rad_s2),
        float(settle_s),
    )
