"""The twin's arm in time: its moves on the twin's time line, read by the devices at any instant.

The arm keeps a bounded history of its moves on the twin's time line (:mod:`cellctl.sim.timeline`):
a move that starts at line instant T0 is at simulated time tau of its profile at T0 + tau, so the
devices can compute feedback and stored readings analytically (:meth:`RobotArm.belief_at_line`,
:meth:`RobotArm.true_at_line`). The physics of each move (accuracy, repeatability, reach, timing and
the deviation at speed) is :class:`cellctl.sim.robot.RobotModel`'s.
"""

from __future__ import annotations

import bisect
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.geometry.motion import PathTiming, interpolate_pose
from cellctl.geometry.pose import Pose, check_pose, make_pose
from cellctl.sim.robot import RobotModel
from cellctl.sim.timeline import TwinTimeline

# Moves (and rests) the arm remembers on the time line; older ones are forgotten.
HISTORY_LEGS = 4096


class RobotBusy(RuntimeError):
    """A new motion was asked for while the previous one is still running."""


def path_rate(timing: PathTiming, tau: float) -> float:
    """ds/dt (1/s) of the path fraction ``tau`` simulated seconds into a move: 0 at rest."""
    tr, rot = timing.translation, timing.rotation
    leader = tr if tr.duration >= rot.duration else rot
    T = leader.duration
    if leader.distance == 0.0 or tau <= 0.0 or tau >= T:
        return 0.0
    v, a = leader.peak_speed, leader.acceleration
    speed = min(v, a * tau, a * (T - tau))
    return speed / leader.distance


@dataclass(frozen=True)
class Motion:
    """One move in progress (or finished), on the arm's clock and on the time line.

    The target's true pose is drawn when the move starts; along the way the belief and the truth
    are both interpolated with the same path fraction, the truth lagging by ``lag_s`` and pushed
    sideways by ``sideways_mm`` times the path rate (see :meth:`RobotModel.path_deviation`).
    ``tau`` is simulated seconds since the start: clock time ``t_start + tau * time_scale``, line
    instant ``line_start + tau``.
    """

    start_belief: Pose
    target_belief: Pose
    start_true: Pose
    target_true: Pose
    timing: PathTiming | None
    t_start: float
    time_scale: float
    line_start: float = 0.0
    lag_s: float = 0.0
    sideways_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    deform: Callable[[Pose], Pose] | None = None  # the accuracy field E(X) along the path (None: the ends' truth interpolated)

    @property
    def duration_s(self) -> float:
        """Simulated seconds of the move, settling included (0 at rest)."""
        return 0.0 if self.timing is None else self.timing.duration_s

    @property
    def t_end(self) -> float:
        """Clock time when the move (settling included) is over."""
        return self.t_start + self.duration_s * self.time_scale

    def tau(self, now: float) -> float:
        """Simulated seconds into the move at clock time ``now`` (inf when time does not scale)."""
        if self.timing is None or self.time_scale == 0.0:
            return math.inf
        return (now - self.t_start) / self.time_scale

    def fraction(self, now: float) -> float:
        """Path fraction at clock time ``now``."""
        return 1.0 if self.timing is None else self.timing.fraction(self.tau(now))

    def belief_at_tau(self, tau: float) -> Pose:
        """What the controller reports ``tau`` simulated seconds into the move."""
        if self.timing is None:
            return self.target_belief.copy()
        return interpolate_pose(self.start_belief, self.target_belief, self.timing.fraction(tau))

    def true_at_tau(self, tau: float, *, deviate: bool = True) -> Pose:
        """Where the flange really is ``tau`` simulated seconds into the move (``deviate``: with the path deviation)."""
        if self.timing is None or tau >= self.timing.duration_s:
            return self.target_true.copy()
        lagged = tau - self.lag_s if deviate else tau
        f = self.timing.fraction(lagged)
        T = interpolate_pose(self.start_true, self.target_true, f) if self.deform is None else self._true_on_path(f)
        rate = path_rate(self.timing, lagged) if deviate else 0.0
        if rate > 0.0:
            T[:3, 3] += rate * self.sideways_mm
        return T

    def _true_on_path(self, f: float) -> Pose:
        """The truth at path fraction f: the accuracy field at the belief there (a real arm's kinematic errors
        act all along its path), the ends' repeatability blended."""
        if f >= 1.0:
            return self.target_true.copy()
        if f <= 0.0:
            return self.start_true.copy()
        assert self.deform is not None
        N = interpolate_pose(*self._ends_noise, f)
        E = self.deform(interpolate_pose(self.start_belief, self.target_belief, f))
        return make_pose(N[:3, :3] @ E[:3, :3], E[:3, 3] + N[:3, 3])

    @cached_property
    def _ends_noise(self) -> tuple[Pose, Pose]:
        """The repeatability noise N at the start and the target (truth = N E(belief)); once per move."""
        assert self.deform is not None
        ends = ((self.start_true, self.deform(self.start_belief)), (self.target_true, self.deform(self.target_belief)))
        n0, n1 = (make_pose(T[:3, :3] @ E[:3, :3].T, T[:3, 3] - E[:3, 3]) for T, E in ends)
        return n0, n1

    def belief_at(self, now: float) -> Pose:
        """What the controller reports at clock time ``now``."""
        return self.belief_at_tau(self.tau(now))

    def true_at(self, now: float, *, deviate: bool = True) -> Pose:
        """Where the flange really is at clock time ``now``."""
        return self.true_at_tau(self.tau(now), deviate=deviate)


Waited = Callable[[float, str], None]
"""Told the simulated seconds of a wait as it begins, and what they are spent on."""


def _tell_both(first: Waited, second: Waited) -> Waited:
    """One ``waited`` callback that tells both."""

    def waited(simulated_s: float, spent_on: str) -> None:
        first(simulated_s, spent_on)
        second(simulated_s, spent_on)

    return waited


def spent_on_move(timing: PathTiming, speed_mm_s: float, speed_deg_s: float) -> str:
    """What a move's time goes to, by what leads it: the translation at its speed, or the reorientation at its."""
    if timing.rotation.duration > timing.translation.duration:
        return f"turns at {speed_deg_s:g} deg/s"
    return f"moves at {speed_mm_s:g} mm/s"


class RobotArm:
    """The robot's state: the last (or current) motion, read against a clock, and its history on the time line.

    Args:
        model: the robot's physics.
        time_scale: real seconds per simulated second (0: moves complete instantly).
        clock: monotonic real time in seconds.
        waited: told the simulated seconds of each move as it starts (and, negative, the part a stop cut off),
            with what they are spent on (:func:`spent_on_move`).
        line: the twin's time line (s), read as each move starts; None: the arm keeps its own
            (:class:`TwinTimeline` on ``clock``). Given, ``waited`` must advance it.
    """

    def __init__(
        self,
        model: RobotModel,
        *,
        time_scale: float,
        clock: Callable[[], float] = time.monotonic,
        waited: Waited = lambda _s, _on: None,
        line: Callable[[], float] | None = None,
    ) -> None:
        if not np.isfinite(time_scale) or time_scale < 0:
            raise ValueError(f"time_scale must be a finite non-negative number, got {time_scale}")
        self.model = model
        self.time_scale = float(time_scale)
        self._clock = clock
        if line is None:
            own = TwinTimeline(self.time_scale, clock)
            line, waited = own.now, _tell_both(own.waited, waited)
        self._line = line
        self._waited = waited
        self._legs: list[Motion] = []
        self._starts: list[float] = []
        self._clock_starts: list[float] = []
        self._forgot = False
        self._spent_on = "moves"  # what the current move's time is spent on
        home = model.config.T_B_H_home()
        true = model.deform(home)
        self._motion = self._record(Motion(home, home, true, true, None, clock(), self.time_scale, line()))

    def now(self) -> float:
        """The arm's clock."""
        return self._clock()

    def _record(self, motion: Motion) -> Motion:
        """Make ``motion`` the current one and remember it on the time line."""
        if self._starts and motion.line_start < self._starts[-1]:
            motion = replace(motion, line_start=self._starts[-1])
        self._legs.append(motion)
        self._starts.append(motion.line_start)
        self._clock_starts.append(max(motion.t_start, self._clock_starts[-1]) if self._clock_starts else motion.t_start)
        if len(self._legs) > HISTORY_LEGS:
            del self._legs[0], self._starts[0], self._clock_starts[0]
            self._forgot = True
        self._motion = motion
        return motion

    def _leg_at(self, t: float, starts: list[float] | None = None) -> Motion:
        i = bisect.bisect_right(self._starts if starts is None else starts, t) - 1
        if i < 0:
            if self._forgot:
                raise LookupError(f"instant {t:.6f} s is older than the arm's history (its last {HISTORY_LEGS} moves)")
            i = 0
        return self._legs[i]

    def true_at_clock(self, t: float) -> Pose:
        """The true flange pose at instant ``t`` of the arm's clock (s), deviation at speed included; or LookupError.

        For a device reading the arm by its own clock: the time line may stand still meanwhile, this clock does not.
        """
        return self._leg_at(t, self._clock_starts).true_at(t)

    def belief_at_line(self, t: float) -> Pose:
        """The flange pose the controller reports at time-line instant ``t`` (s); LookupError if forgotten."""
        leg = self._leg_at(t)
        return leg.belief_at_tau(t - leg.line_start)

    def true_at_line(self, t: float) -> Pose:
        """The true flange pose at time-line instant ``t`` (s), deviation at speed included; or LookupError."""
        leg = self._leg_at(t)
        return leg.true_at_tau(t - leg.line_start)

    def belief_pose(self) -> Pose:
        """The flange pose the controller reports (interpolated while moving)."""
        return self._motion.belief_at(self._clock())

    def true_pose(self) -> Pose:
        """Where the flange really is (interpolated while moving, path deviation included)."""
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
        lag_s, sideways = self.model.path_deviation(start_belief, target)
        motion = Motion(
            start_belief, target, start_true, target_true, timing, now, self.time_scale, self._line(), lag_s, sideways,
            self.model.deform,
        )
        self._record(motion)
        self._spent_on = spent_on_move(timing, *self.model.speeds(speed_mm_s, speed_deg_s))
        self._waited(timing.duration_s, self._spent_on)
        return motion

    def stop(self) -> Pose:
        """Stop where the flange is now; returns the belief pose it stopped at.

        The flange rests where the path (without its deviation at speed) had brought it.
        """
        now = self._clock()
        m = self._motion
        if m.timing is not None and now < m.t_end and self.time_scale > 0:
            self._waited(-(m.t_end - now) / self.time_scale, self._spent_on)
            line = m.line_start + m.tau(now)
        else:
            line = self._line()
        belief = m.belief_at(now)
        true = m.true_at(now, deviate=False)
        self._record(Motion(belief, belief, true, true, None, now, self.time_scale, line))
        return belief

    def execute(self, X: ArrayLike) -> Pose:
        """Move to belief X at once (no motion time); returns the true flange pose reached.

        For callers that keep their own time, such as a protocol fake of the robot controller.
        """
        target = check_pose(X, "robot target")
        true = self.model.execute(target)
        self._record(Motion(target, target, true, true, None, self._clock(), self.time_scale, self._line()))
        return true
