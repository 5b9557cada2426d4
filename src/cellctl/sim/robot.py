"""The twin's ABB IRB 7600-325: what the controller believes versus where the flange really is.

For a commanded (believed) flange pose X the flange really reaches ``T_true = N * E(X)`` (base frame):

- E(X), absolute accuracy: a smooth deformation fixed per robot (drawn once from its seed),
  evaluated at the wrist centre, bounded by ``absolute_accuracy_mm`` / ``absolute_accuracy_deg``.
  It barely changes over tens of mm, so taught poses and relative moves cancel most of it.
- N, repeatability: drawn per move. ISO 9283's RP = mean(l) + 3 S_l is 3.616 sigma for an
  isotropic 3-D Gaussian, so sigma = RP / 3.616 per axis (0.0277 mm for the IRB 7600's 0.1 mm);
  orientation RP_a = 3 S, so sigma = RP_a / 3 about each base axis.

Reading the pose back returns the belief, as a real controller does.

During a move the true flange also deviates from the reported path, zero at rest: it lags behind
it by ``path_lag_s`` (the servo lag; along the path, v * lag mm) and is pushed sideways by
``path_sideways_s`` * v mm (v the TCP speed in mm/s) in a direction fixed per robot and path
direction. The controller reports the motor-side path (the belief), never that deflection.

The arm that moves in time on the twin's time line is :mod:`cellctl.sim.arm`.
"""

from __future__ import annotations

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

# The stream of the per-robot direction of the sideways path deviation at speed.
ROBOT_PATH = "robot.path"


class ReachError(ValueError):
    """A target (or the path to it) lies outside the robot's working range.

    Attributes:
        distance_mm: the wrist centre's distance from the reach centre at the offending pose.
    """

    def __init__(self, message: str, distance_mm: float) -> None:
        super().__init__(message)
        self.distance_mm = distance_mm


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
        axis = rng_stream(seed, ROBOT_PATH).normal(size=3)
        self._sideways_axis = axis / np.linalg.norm(axis)

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

    def path_deviation(self, X_from: ArrayLike, X_to: ArrayLike) -> tuple[float, NDArray[np.float64]]:
        """The deviation at speed of a move: the servo lag (s) and the sideways offset (mm) per unit path rate (1/s).

        The sideways direction is the robot's fixed axis made perpendicular to the path (base frame);
        the offset at path rate ds/dt is ``sideways * ds/dt``, i.e. ``path_sideways_s`` times the TCP speed.
        """
        delta = np.asarray(X_to, dtype=float)[:3, 3] - np.asarray(X_from, dtype=float)[:3, 3]
        length = float(np.linalg.norm(delta))
        sideways = np.zeros(3)
        if length > 0.0:
            across = self._sideways_axis - (self._sideways_axis @ delta) / length**2 * delta
            norm = float(np.linalg.norm(across))
            if norm > 1e-9:
                sideways = self.config.path_sideways_s * length * across / norm
        return float(self.config.path_lag_s), sideways

    # -- motion time ----------------------------------------------------------------------------

    def speeds(self, speed_mm_s: float | None, speed_deg_s: float | None) -> tuple[float, float]:
        """The TCP speed (mm/s) and reorientation speed (deg/s) a move runs at: as requested, capped at the robot's limits."""
        c = self.config
        v = c.max_speed_mm_s if speed_mm_s is None else min(float(speed_mm_s), c.max_speed_mm_s)
        w = c.max_speed_deg_s if speed_deg_s is None else min(float(speed_deg_s), c.max_speed_deg_s)
        return v, w

    def timing(
        self, X_from: ArrayLike, X_to: ArrayLike, speed_mm_s: float | None = None, speed_deg_s: float | None = None
    ) -> PathTiming:
        """The timing of a move; the requested speeds are capped at the robot's limits."""
        c = self.config
        v, w = self.speeds(speed_mm_s, speed_deg_s)
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
