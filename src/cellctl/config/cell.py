"""The cell's process settings: working distance, tolerances, alignment spots and gates."""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, PrivateAttr, ValidationError, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

from cellctl.config.inspection import InspectionConfig
from cellctl.config.recipe import Recipe
from cellctl.config.spc import SpcConfig, drift_limit_problems
from cellctl.config.types import Finite, StrictModel, Vec2, check_unique
from cellctl.geometry.plane import PlaneFitError, fit_plane
from cellctl.inspection.flush_crossing import Opening, crossing_path_problem


class ToleranceConfig(StrictModel):
    """Install tolerance (paper: +-0.5 mm, +-1 deg)."""

    position_mm: Finite = Field(0.5, gt=0)
    orientation_deg: Finite = Field(1.0, gt=0)


class SweepConfig(StrictModel):
    """Reading the wall on the move (issue 19): the laser stores readings while the flange sweeps a path.

    ``path_mm`` are the corners of the path the laser spot follows on the wall, in T0 like
    ``spots_mm`` (keep every leg on the wall, off the opening). At the first corner the flange
    moves in, out and in again along the beam by ``approach_mm``: those moves time the laser against
    the robot's feedback (the latency between the two is estimated from them). The service keeps the
    latency: it times it so in its first sweep, every ``retime_every`` sweeps, after a failed cycle
    and when a check disagrees; the sweeps between move in once along the beam and check the kept
    latency against that move (within ``latency_check_tolerance_s``, else that sweep uses what the
    check found and the next one times anew). Used when the laser can store readings and the robot
    streams its position; else the cell reads at standing spots.
    """

    # Along the top, down the side and back up to the corner beside the window's: a second stop there (its own
    # draw of the robot's error) steadies the plane where the camera looks, and the shooting pose is a short move on.
    # The first corner (where the laser is timed) stands 100 mm above the opening: 1.5 m from the window's corner,
    # a car body turned 2 deg and moved 20 mm puts it up to 73 mm lower, and at 60 mm the beam went through the opening.
    path_mm: tuple[Vec2, ...] = ((-1500.0, -100.0), (60.0, -60.0), (60.0, 1200.0), (60.0, -60.0))
    # At most process.motion's travel speed for what the gripper holds (ProcessConfig.sweep_speed_mm_s): the
    # alignment's sweep carries the glass, the inspection's does not. The laser stores every 10 mm at 1000 mm/s.
    speed_mm_s: Finite = Field(1000.0, gt=0, le=2000)
    approach_mm: Finite = Field(40.0, gt=5, le=200)
    # The LK-G's storage cycle. Each stored reading costs 0.78 ms of read-out at 115200 Bd after the sweep:
    # at 2 ms that is 39 % of the sweep's time again (8 s a cycle), at 5 ms 16 %, at 10 ms 8 %, at no cost in
    # accuracy (cellctl bench cycle-time): the fit keeps max_points of them, the flush every one beside its crossings.
    storage_cycle_s: Finite = Field(0.01, ge=2e-5, le=1.0)
    max_points: int = Field(400, ge=20, le=20000)  # readings used in the plane fit, spread evenly along the path
    latency_search_s: tuple[Finite, Finite] = (-0.01, 0.05)
    max_latency_sigma_s: Finite = Field(0.0005, gt=0)  # a worse estimate fails the alignment
    # The latency (s) when it is known (from commissioning): the sweep then skips the moves along the beam
    # and neither estimates nor checks it. None (the default): timed and checked as above.
    fixed_latency_s: float | None = Field(None, ge=-0.1, le=0.5)
    retime_every: int = Field(25, ge=1, le=100000)  # sweeps from one timing (in, out, in) to the next; 1: every sweep
    latency_check_tolerance_s: Finite = Field(0.001, gt=0, le=0.05)  # a check further from the kept latency: time anew
    feedback_stale_s: Finite = Field(0.05, gt=0, le=5)  # the robot's feedback older than this: stop the robot, alarm 1402
    max_feedback_gap_s: Finite = Field(0.02, gt=0, le=1)  # no pose is guessed across a longer gap in the feedback
    min_paired_share: Finite = Field(0.9, gt=0, le=1)  # of the legs' readings with a distance, at least this share needs a pose

    def _leg_steps(self, step_mm: float) -> list[int]:
        corners = np.asarray(self.path_mm, dtype=float)
        return [max(1, int(np.ceil(np.linalg.norm(b - a) / step_mm))) for a, b in zip(corners[:-1], corners[1:])]

    def points_along_mm(self, step_mm: float = 100.0) -> tuple[tuple[float, float], ...]:
        """Points on the path every ``step_mm`` or less (its corners included), in T0 (mm)."""
        corners = np.asarray(self.path_mm, dtype=float)
        out = [corners[0]]
        for a, b, n in zip(corners[:-1], corners[1:], self._leg_steps(step_mm)):
            out += [a + (b - a) * k / n for k in range(1, n + 1)]
        return tuple((float(p[0]), float(p[1])) for p in out)

    def corners_along(self, step_mm: float = 100.0) -> tuple[int, ...]:
        """The indices of the path's corners (where the sweep stands) in :meth:`points_along_mm`."""
        return tuple(int(k) for k in np.concatenate([[0], np.cumsum(self._leg_steps(step_mm))]))

    @model_validator(mode="after")
    def _path(self) -> "SweepConfig":
        if len(self.path_mm) < 3:
            raise ValueError("path_mm needs at least 3 corners (two legs), so the readings span the wall in two directions")
        for k, (a, b) in enumerate(zip(self.path_mm, self.path_mm[1:])):
            if a == b:
                raise ValueError(f"path_mm corners {k} and {k + 1} are the same point {list(a)}: a leg needs a length; drop one of them")
        lo, hi = self.latency_search_s
        if not lo < hi:
            raise ValueError(f"latency_search_s must be [min, max] with min < max, got {list(self.latency_search_s)}")
        return self


class AlignConfig(StrictModel):
    """Laser alignment (paper section 3).

    ``spots_mm`` are where the laser should hit the wall, in the taught workpiece frame T0
    (x right, y down from the upper-right corner; the opening is x < 0, 0 < y). Keep them on the
    wall, off the opening, and spread in two directions. ``mode = "on_the_fly"`` reads the wall
    while sweeping ``[process.align.sweep]`` instead, where the devices can (else standing, at the
    points along the sweep's path that teaching read: :meth:`wall_spots_mm`).
    """

    spots_mm: tuple[Vec2, ...] = (
        (-1500.0, -60.0),
        (-500.0, -60.0),
        (60.0, 300.0),
        (60.0, 1200.0),
        (-1000.0, 1560.0),
        (-2060.0, 750.0),
    )
    laser_standoff_mm: Finite = Field(350.0, gt=0)
    laser_range_mm: Vec2 = (250.0, 450.0)  # the sensor head's measuring range (LK-G500); readings outside are refused
    max_rms_mm: Finite = Field(0.2, gt=0)
    inlier_threshold_mm: Finite = Field(0.5, gt=0)
    min_collinearity: Finite = Field(1e-3, gt=0, lt=1)
    mode: Literal["stop_and_go", "on_the_fly"] = "stop_and_go"
    sweep: SweepConfig = SweepConfig()

    def wall_spots_mm(self) -> tuple[tuple[float, float], ...]:
        """Where the alignment reads the wall: the spots, or on the move points along the sweep's path.

        Teaching reads these standing, so the taught plane comes from the part of the wall the
        cycles measure (the robot's accuracy errors there then cancel between the two).
        """
        return self.spots_mm if self.mode == "stop_and_go" else self.sweep.points_along_mm()

    def wall_setting(self) -> str:
        """The setting that says where the alignment reads the wall (for the messages that ask to move it)."""
        return "process.align.spots_mm" if self.mode == "stop_and_go" else "process.align.sweep.path_mm"

    def wall_stops(self) -> tuple[int, ...]:
        """The indices in :meth:`wall_spots_mm` where a sweep stands (its path's corners); none at stop and go.

        Teaching takes the plane's offset from these, as the cycle on the move takes it from its stops.
        """
        return () if self.mode == "stop_and_go" else self.sweep.corners_along()

    @model_validator(mode="after")
    def _standoff_in_range(self) -> "AlignConfig":
        lo, hi = self.laser_range_mm
        if not 0 < lo < hi:
            raise ValueError(f"laser_range_mm must be [min, max] with 0 < min < max, got {list(self.laser_range_mm)}")
        if not lo < self.laser_standoff_mm < hi:
            raise ValueError(f"laser_standoff_mm ({self.laser_standoff_mm:g}) must lie inside laser_range_mm {list(self.laser_range_mm)}")
        return self

    @model_validator(mode="after")
    def _enough_spots(self) -> "AlignConfig":
        if len(self.spots_mm) < 3:
            raise ValueError(f"spots_mm has {len(self.spots_mm)} spots; the plane needs at least 3")
        return self

    @model_validator(mode="after")
    def _spread_in_two_directions(self) -> "AlignConfig":
        """The readings must fix the wall's tilt in both directions: the wall fit refuses points on one line."""
        readings = (
            ("spots_mm", self.spots_mm, f"{len(self.spots_mm)} spots"),
            ("sweep.path_mm", self.sweep.points_along_mm(), f"path's {len(self.sweep.path_mm)} corners and legs"),
        )
        for field, points, what in readings:
            problem = one_line_problem(points, self.min_collinearity)
            if problem is not None:
                raise ValueError(
                    f"{field}: the {what} {problem}, so the wall's tilt about that line is undetermined "
                    "and every alignment would fail: spread them in two directions (along the top edge and down the "
                    "side, as config/sim.toml does)"
                )
        return self


def one_line_problem(points_mm: tuple[tuple[float, float], ...], min_collinearity: float) -> str | None:
    """Why 2-D wall points cannot fix a plane (on one point, or on one line), or None.

    The wall fit's criterion (:func:`cellctl.geometry.plane.fit_plane`): lambda_mid / lambda_max of the
    points' centred scatter, below ``min_collinearity`` (process.align.min_collinearity) they are on a line.
    """
    P = np.asarray(points_mm, dtype=float).reshape(-1, 2)
    try:
        fit = fit_plane(np.column_stack([P, np.zeros(len(P))]), min_collinearity=0.0)
    except PlaneFitError:
        return "stand on one point"
    if fit.collinearity < min_collinearity:
        return (f"lie on one line (lambda_mid/lambda_max of their spread is {fit.collinearity:.3g}, below "
                f"process.align.min_collinearity = {min_collinearity:g})")
    return None


class MotionConfig(StrictModel):
    """Speeds and timeouts of the cycle's robot moves."""

    travel_speed_mm_s: Finite = Field(500.0, gt=0, le=7000)  # between spots, to the shooting pose
    fine_speed_mm_s: Finite = Field(50.0, gt=0, le=1000)  # the last approach into the opening
    speed_deg_s: Finite = Field(30.0, gt=0, le=500)
    # Once the gripper has released the glass (the inspection's moves) the robot carries no glass;
    # None: the speeds above (back_off_speed_mm_s: the move out of the opening, None: fine_speed_mm_s).
    empty_travel_speed_mm_s: Finite | None = Field(None, gt=0, le=7000)
    empty_speed_deg_s: Finite | None = Field(None, gt=0, le=500)
    back_off_speed_mm_s: Finite | None = Field(None, gt=0, le=1000)
    approach_mm: Finite = Field(100.0, ge=0)  # stand-off in front of the install pose
    move_timeout_s: Finite = Field(60.0, gt=0)
    read_timeout_s: Finite = Field(2.0, gt=0)  # laser reading, pose read-back
    grab_timeout_s: Finite = Field(5.0, gt=0)
    # The verification moves stream through EGM where the robot's driver offers it (no stop-and-go RAPID
    # move), until the reported pose is within these; a driver without EGM, or one that refuses the
    # correction (larger than its egm_max_correction_mm / _deg), takes the RAPID move.
    verify_by_egm: bool = True
    egm_tolerance_mm: Finite = Field(0.02, gt=0, le=5)
    egm_tolerance_deg: Finite = Field(0.005, gt=0, le=1)

    def speeds(self, *, glass_on_gripper: bool) -> tuple[float, float]:
        """The travel speed (mm/s) and reorientation speed (deg/s) of a move, with the glass on the gripper or not."""
        if glass_on_gripper:
            return self.travel_speed_mm_s, self.speed_deg_s
        return self.empty_travel_speed_mm_s or self.travel_speed_mm_s, self.empty_speed_deg_s or self.speed_deg_s

    def back_off_mm_s(self) -> float:
        """The speed (mm/s) of the move out of the opening after the release."""
        return self.back_off_speed_mm_s or self.fine_speed_mm_s


class VerifyConfig(StrictModel):
    """Verification shots: re-shoot at the corrected shooting pose until the residual is small.

    Each verification shot, taken after a fresh move, is an independent estimate of the workpiece
    frame whose error is mostly the robot's repeatability at that move; the cell installs on the
    mean of the verification estimates. ``residual_mm``/``residual_deg`` should sit above the
    robot's repeatability (about 3 sigma), or the loop chases noise.
    """

    # The first shot only aims the verification shots, so its corner may be near the image border
    # (a car body far off its nominal posture) with short straight edges: looser gates for it.
    first_shot_sigma_px: Finite = Field(0.5, gt=0)
    first_shot_min_edge_points: int = Field(30, ge=10)
    min_shots: int = Field(2, ge=1, le=10)  # verification shots averaged at least
    max_shots: int = Field(4, ge=1, le=10)  # give up (Hold) when still not converged after these
    residual_mm: Finite = Field(0.1, gt=0)
    residual_deg: Finite = Field(0.05, gt=0)

    @model_validator(mode="after")
    def _order(self) -> "VerifyConfig":
        if self.min_shots > self.max_shots:
            raise ValueError(f"min_shots ({self.min_shots}) must not exceed max_shots ({self.max_shots})")
        return self


class LimitsConfig(StrictModel):
    """How far a correction may move the robot from its taught pose.

    Keep them above what the car body's posture range can ask for: +-20 mm and +-2 deg about each
    axis move the install pose (the flange ~1.25 m from the corner) by up to ~110 mm and 3.5 deg.
    """

    max_correction_mm: Finite = Field(150.0, gt=0)
    max_correction_deg: Finite = Field(8.0, gt=0, le=45)
    max_verify_step_mm: Finite = Field(5.0, gt=0)  # one verification shot's correction
    max_verify_step_deg: Finite = Field(0.5, gt=0)


class ProcessConfig(StrictModel):
    """What the cell does each cycle."""

    working_distance_mm: Finite = Field(400.0, gt=0)
    tolerance: ToleranceConfig = ToleranceConfig()
    align: AlignConfig = AlignConfig()
    motion: MotionConfig = MotionConfig()
    verify: VerifyConfig = VerifyConfig()
    limits: LimitsConfig = LimitsConfig()
    inspect: InspectionConfig = InspectionConfig()
    spc: SpcConfig = SpcConfig()
    recipes: tuple[Recipe, ...] = (Recipe(id=1, name="side-window", description="2000 x 1500 mm side-window glass"),)

    # The outline of the opening this process works on (T, mm): the configuration's layout sets it (a recipe's view,
    # the recipe's), since the flush sweep tells glass from wall by it. None: a process outside a configuration.
    _opening: Opening | None = PrivateAttr(default=None)

    @property
    def opening(self) -> Opening | None:
        """The outline of the opening this process works on (``[layout.opening]``, a recipe's own in its view)."""
        return self._opening

    def on_opening(self, opening: Opening) -> "ProcessConfig":
        """This process, working on ``opening`` (CellConfig sets it); a copy where another configuration's opening holds it."""
        if self._opening is not None and self._opening != opening:
            other = self.model_copy()
            other._opening = opening
            return other
        self._opening = opening
        return self

    def flush_sweep_problem(self, opening: Opening) -> str | None:
        """Why, where the cell reads on the move and inspects, its flush sweep cannot cross the edges of ``opening``
        (checked only then), or None; the message starts with the field."""
        insp = self.inspect
        if self.align.mode != "on_the_fly" or not insp.enabled:
            return None
        problem = crossing_path_problem(insp.sweep_path_mm, insp.nominal_gap_mm, insp.sweep_margin_mm, opening)
        return None if problem is None else f"process.inspect.sweep_path_mm: {problem}"

    @model_validator(mode="after")
    def _drift_limits_inside_the_tolerance(self) -> "ProcessConfig":
        """[process.spc]'s drift limits below [process.tolerance] (recipes set neither), each refused at its field."""
        tol = self.tolerance
        problems = drift_limit_problems(self.spc, tol.position_mm, tol.orientation_deg)
        if problems:
            errors = [InitErrorDetails(type=PydanticCustomError("drift_limit_not_below_tolerance", text),
                                       loc=("spc", name), input=getattr(self.spc, name)) for name, text in problems.items()]  # fmt: skip
            raise ValidationError.from_exception_data(type(self).__name__, errors)
        return self

    @model_validator(mode="after")
    def _unique_recipes(self) -> "ProcessConfig":
        if not self.recipes:
            raise ValueError("recipes: give at least one recipe (id and name)")
        for what in ("id", "name"):
            check_unique("recipes", what, [getattr(r, what) for r in self.recipes])
        return self

    def sweep_speed_mm_s(self, *, glass_on_gripper: bool) -> float:
        """A sweep's TCP speed (mm/s): align.sweep.speed_mm_s, at most motion's travel speed for what the gripper holds."""
        return min(self.align.sweep.speed_mm_s, self.motion.speeds(glass_on_gripper=glass_on_gripper)[0])

    def recipe_names(self) -> dict[int, str]:
        """PLC recipe number -> recipe name."""
        return {r.id: r.name for r in self.recipes}
