"""The twin's ABB IRB 7600-325: what the controller believes versus where the flange really is.

For a commanded (believed) flange pose X the flange really reaches ``T_true = N * E(X)`` (base frame):

- E(X), absolute accuracy: a smooth deformation fixed per robot (drawn once from its seed),
  evaluated at the wrist centre, bounded by ``absolute_accuracy_mm`` / ``absolute_accuracy_deg``.
  It barely changes over tens of mm, so taught poses and relative moves cancel most of it.
- N, repeatability: drawn per move. ISO 9283's RP = mean(l) + 3 S_l is 3.616 sigma for an
  isotropic 3-D Gaussian, so sigma = RP / 3.616 per axis (0.0277 mm for the IRB 7600's 0.1 mm);
  orientation RP_a = 3 S, so sigma = RP_a / 3 about each base axis.

Reading the pose back returns the belief, as a real controller does.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.config.layout import RobotEnvelope
from cellctl.config.sim import RobotSimConfig
from cellctl.geometry.motion import PathTiming, interpolate_pose, path_timing
from cellctl.geometry.pose import Pose, check_pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix, nearest_rotation
from cellctl.sim.fields import SmoothRandomField
from cellctl.sim.streams import ROBOT_ACCURACY, ROBOT_REPEATABILITY, rng_stream

# ISO 9283 RP = mean(l) + 3 S_l for a 3-D isotropic Gaussian, in units of the per-axis sigma.
ISO_9283_RP_PER_SIGMA = 2.0 * np.sqrt(2.0 / np.pi) + 3.0 * np.sqrt(3.0 - 8.0 / np.pi)

# How many points of a linear path the reach check visits.
PATH_CHECK_POINTS = 16

# Plane waves in each accuracy field. With three, the field's peak over the reachable workspace
# is typically 65-95 % of the configured bound (which it can never exceed).
ACCURACY_MODES = 3


class ReachError(ValueError):
    """A target (or the path to it) lies outside the robot's working range.

    Attributes:
        distance_mm: the wrist centre's distance from the reach centre at the offending pose.
    """

    def __init__(self, message: str, distance_mm: float) -> None:
        super().__init__(message)
        self.distance_mm = distance_mm


class RobotBusy(RuntimeError):
    """A new motion was asked for while the previous one is still running."""


class RobotModel:
    """The physics of one robot: accuracy deformation, repeatability, reach and motion time.

    Args:
        config: the robot's section of the twin's configuration.
        seed: the cell's seed; the accuracy field and the repeatability noise draw from their own
            streams (see :mod:`cellctl.sim.streams`).
    """

    def __init__(self, config: RobotSimConfig, seed: int) -> None:
        self.config = config
        self._envelope = RobotEnvelope(
            reach_mm=config.reach_mm, min_reach_mm=config.min_reach_mm,
            reach_centre_mm=config.reach_centre_mm, wrist_to_flange_mm=config.wrist_to_flange_mm,
        )  # fmt: skip
        accuracy_rng = rng_stream(seed, ROBOT_ACCURACY)
        self._position_field = SmoothRandomField(
            accuracy_rng,
            config.absolute_accuracy_mm,
            min_wavelength=config.accuracy_wavelength_mm,
            n_modes=ACCURACY_MODES,
        )
        self._orientation_field = SmoothRandomField(
            accuracy_rng,
            float(np.deg2rad(config.absolute_accuracy_deg)),
            min_wavelength=config.accuracy_wavelength_mm,
            n_modes=ACCURACY_MODES,
        )
        self._noise_rng = rng_stream(seed, ROBOT_REPEATABILITY)
        self.sigma_position_mm = config.repeatability_mm / ISO_9283_RP_PER_SIGMA
        self.sigma_orientation_rad = float(np.deg2rad(config.repeatability_orientation_deg)) / 3.0

    # -- geometry -------------------------------------------------------------------------------

    def wrist_centre(self, X: ArrayLike) -> NDArray[np.float64]:
        """The wrist centre (axis 5) of flange pose X: the flange origin moved back along its z axis."""
        return self._envelope.wrist_centre(X)

    def reach_distance(self, X: ArrayLike) -> float:
        """The wrist centre's distance (mm) from the reach centre."""
        return self._envelope.reach_distance(X)

    def check_reach(self, X: ArrayLike, what: str = "target") -> None:
        """Raise :class:`ReachError` if flange pose X is outside the working range."""
        problem = self._envelope.reach_problem(X, what)
        if problem is not None:
            raise ReachError(problem, self.reach_distance(X))

    def check_path(self, X_from: ArrayLike, X_to: ArrayLike) -> None:
        """Raise :class:`ReachError` if a linear move between the poses leaves the working range."""
        self.check_reach(X_to)
        for s in np.linspace(0.0, 1.0, PATH_CHECK_POINTS)[1:-1]:
            self.check_reach(interpolate_pose(X_from, X_to, float(s)), f"the linear path ({s:.0%} along)")

    # -- accuracy and repeatability -------------------------------------------------------------

    def accuracy_error(self, X: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """E at pose X: position error (mm) and rotation-vector error (rad), both in the base frame."""
        w = self.wrist_centre(X)
        return self._position_field(w), self._orientation_field(w)

    def deform(self, X: ArrayLike) -> Pose:
        """E(X): where the flange goes for belief X, without repeatability noise."""
        M = check_pose(X, "robot target")
        dp, dtheta = self.accuracy_error(M)
        return make_pose(axis_angle_to_matrix(dtheta) @ M[:3, :3], M[:3, 3] + dp)

    def command_for(self, T_true: ArrayLike, *, tol: float = 1e-12, max_iter: int = 50) -> Pose:
        """The belief X with E(X) = T_true: what to command so the flange (noise aside) lands on T_true.

        E is a small, slowly varying deformation, so fixed-point iteration converges in a few steps.
        """
        T = check_pose(T_true, "true flange pose")
        X = T.copy()
        for _ in range(max_iter):
            E = self.deform(X)
            dp = E[:3, 3] - T[:3, 3]
            dR = E[:3, :3] @ T[:3, :3].T
            X = make_pose(dR.T @ X[:3, :3], X[:3, 3] - dp)
            if np.linalg.norm(dp) < tol and np.linalg.norm(dR - np.eye(3)) < tol:
                break
        return make_pose(nearest_rotation(X[:3, :3]), X[:3, 3])

    def draw_noise(self) -> Pose:
        """One move's repeatability noise N (a small pose in the base frame).

        Six normal draws every call, even with zero sigmas, so the stream's position depends only
        on the number of moves.
        """
        z = self._noise_rng.normal(size=6)
        return make_pose(axis_angle_to_matrix(z[3:] * self.sigma_orientation_rad), z[:3] * self.sigma_position_mm)

    def execute(self, X: ArrayLike) -> Pose:
        """The true flange pose after a move to belief X: N * E(X). Checks the reach first."""
        M = check_pose(X, "robot target")
        self.check_reach(M)
        E = self.deform(M)
        N = self.draw_noise()
        return make_pose(N[:3, :3] @ E[:3, :3], E[:3, 3] + N[:3, 3])

    # -- motion time ----------------------------------------------------------------------------

    def timing(
        self, X_from: ArrayLike, X_to: ArrayLike, speed_mm_s: float | None = None, speed_deg_s: float | None = None
    ) -> PathTiming:
        """The timing of a move; the requested speeds are capped at the robot's limits."""
        c = self.config
        v = c.max_speed_mm_s if speed_mm_s is None else min(float(speed_mm_s), c.max_speed_mm_s)
        w = c.max_speed_deg_s if speed_deg_s is None else min(float(speed_deg_s), c.max_speed_deg_s)
        return path_timing(
            X_from,
            X_to,
            speed_mm_s=v,
            acceleration_mm_s2=c.acceleration_mm_s2,
            speed_rad_s=float(np.deg2rad(w)),
            acceleration_rad_s2=float(np.deg2rad(c.acceleration_deg_s2)),
            settle_s=c.settle_time_s,
        )

    def motion_time(
        self, X_from: ArrayLike, X_to: ArrayLike, speed_mm_s: float | None = None, speed_deg_s: float | None = None
    ) -> float:
        """Seconds a real robot takes from ``X_from`` to ``X_to``, settling at the fine point included."""
        return self.timing(X_from, X_to, speed_mm_s, speed_deg_s).duration_s


@dataclass(frozen=True)
class Motion:
    """One move in progress (or finished), in the clock's seconds.

    The target's true pose is drawn when the move starts; along the way the belief and the truth
    are both interpolated with the same path fraction.
    """

    start_belief: Pose
    target_belief: Pose
    start_true: Pose
    target_true: Pose
    timing: PathTiming | None
    t_start: float
    time_scale: float

    @property
    def t_end(self) -> float:
        """Clock time when the move (settling included) is over."""
        if self.timing is None:
            return self.t_start
        return self.t_start + self.timing.duration_s * self.time_scale

    def fraction(self, now: float) -> float:
        """Path fraction at clock time ``now``."""
        if self.timing is None or self.time_scale == 0.0:
            return 1.0
        return self.timing.fraction((now - self.t_start) / self.time_scale)

    def belief_at(self, now: float) -> Pose:
        """What the controller reports at clock time ``now``."""
        return interpolate_pose(self.start_belief, self.target_belief, self.fraction(now))

    def true_at(self, now: float) -> Pose:
        """Where the flange really is at clock time ``now``."""
        return interpolate_pose(self.start_true, self.target_true, self.fraction(now))


class RobotArm:
    """The robot's state: the last (or current) motion, read against a clock.

    Args:
        model: the robot's physics.
        time_scale: real seconds per simulated second (0: moves complete instantly).
        clock: monotonic real time in seconds.
    """

    def __init__(self, model: RobotModel, *, time_scale: float, clock: Callable[[], float] = time.monotonic) -> None:
        if not np.isfinite(time_scale) or time_scale < 0:
            raise ValueError(f"time_scale must be a finite non-negative number, got {time_scale}")
        self.model = model
        self.time_scale = float(time_scale)
        self._clock = clock
        home = model.config.T_B_H_home()
        true = model.deform(home)
        self._motion = Motion(home, home, true, true, None, clock(), self.time_scale)

    def now(self) -> float:
        """The arm's clock."""
        return self._clock()

    def belief_pose(self) -> Pose:
        """The flange pose the controller reports (interpolated while moving)."""
        return self._motion.belief_at(self._clock())

    def true_pose(self) -> Pose:
        """Where the flange really is (interpolated while moving)."""
        return self._motion.true_at(self._clock())

    def moving(self) -> bool:
        """Whether a move (or its settling) is still under way."""
        return self._clock() < self._motion.t_end

    def start(
        self, X: ArrayLike, speed_mm_s: float | None = None, speed_deg_s: float | None = None, *, linear: bool = True
    ) -> Motion:
        """Begin a move to belief X; raises ReachError or RobotBusy before anything moves.

        A linear move has its whole path checked against the reach; a joint move only its target
        (the joint-space path of the real robot is not modelled).
        """
        target = check_pose(X, "robot target")
        now = self._clock()
        if now < self._motion.t_end:
            raise RobotBusy("a motion is still in progress; wait for it or stop it first")
        start_belief = self._motion.belief_at(now)
        start_true = self._motion.true_at(now)
        if linear:
            self.model.check_path(start_belief, target)
        timing = self.model.timing(start_belief, target, speed_mm_s, speed_deg_s)
        target_true = self.model.execute(target)
        self._motion = Motion(start_belief, target, start_true, target_true, timing, now, self.time_scale)
        return self._motion

    def stop(self) -> Pose:
        """Stop where the flange is now; returns the belief pose it stopped at."""
        now = self._clock()
        belief = self._motion.belief_at(now)
        true = self._motion.true_at(now)
        self._motion = Motion(belief, belief, true, true, None, now, self.time_scale)
        return belief

    def execute(self, X: ArrayLike) -> Pose:
        """Move to belief X at once (no motion time); returns the true flange pose reached.

        For callers that keep their own time, such as a protocol fake of the robot controller.
        """
        target = check_pose(X, "robot target")
        true = self.model.execute(target)
        self._motion = Motion(target, target, true, true, None, self._clock(), self.time_scale)
        return true
