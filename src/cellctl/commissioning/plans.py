"""Where each commissioning procedure will move the robot, checked and costed before anything moves.

A plan is a pure function of the cell's configuration (its nominal ``[layout]``: the opening, the
drawn camera and laser mountings, the lens data sheet, the robot's working range) and, for the
procedures that build on earlier ones, the calibration set. Every pose is checked against the
robot's working range (poses outside it are dropped with the reason); the plan reports how many
poses remain, how the rotations between them are spread (hand-eye needs rotation axes in several
directions) and the robot time it will take at the procedure's reduced speed. ``cellctl
calibrate ... --dry-run`` prints it; a job shows it before the first move. A board plan left with fewer
views than its computation accepts (min_views) is refused then, before anything moves.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cellctl.align import plan_spot_poses
from cellctl.calibration.board import BoardSpec
from cellctl.calibration.calibration_set import CalibrationSet, command, parts_of, recipe_named
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.hand_eye import motion_diversity
from cellctl.calibration.pixel_map import nine_point_offsets, nine_point_targets
from cellctl.calibration.poses import PosePlan, plan_board_views, plan_laser_poses
from cellctl.geometry.aiming import nominal_shooting_pose
from cellctl.config.feature import shot_aim_mm
from cellctl.config.calibration_procedure import BoardConfig
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import Pose, pose_in_plane, pose_to_xyz_fixed

PROCEDURE_NAMES = ("camera", "hand_eye", "laser", "teaching", "pixel_map", "verify")
SPREAD_POSES = 60
LASER_SPARE = 0.2
"""Laser poses a job plans beyond the gate's ``calibration.procedure.laser.min_poses`` readings, as a share of
it: a few readings out of the sensor's range (or poses the robot refuses) must not leave the job short."""
MARGIN_WIDTH_PX = 2048
"""The image width (px) calibration.procedure.camera.margin_px is stated for; it scales with layout.camera.width_px."""
MAX_VIEWS = 200
"""The most board views a job may ask for (options.views, cellctl.commissioning.registry.check_options)."""


class PlanError(ValueError):
    """No usable plan: the message says which setting or missing calibration stops it."""


class TooFewViews(PlanError, CalibrationRefused):
    """A board plan with fewer views than its computation accepts: the gate's too_few_views, known before anything moves
    (a job ends refused, as the gate would end it after collecting)."""


@dataclass
class MotionPlan:
    """The robot's route for one procedure.

    Attributes:
        procedure: the procedure's name (:data:`PROCEDURE_NAMES`).
        poses: flange targets T_B_H (mm) in the order they are visited.
        labels: one short name per pose (e.g. "view_003", "stand 4 pose 12").
        dropped: why planned candidates were left out (out of reach, target out of view).
        speed_mm_s, speed_deg_s: the reduced speed every move of the procedure uses.
        moves_s: the estimated robot time of each move, from the previous pose (the first from
            the robot's current pose, when known).
        details: figures particular to the procedure (tilt range, distances, groups).
    """

    procedure: str
    poses: list[Pose]
    labels: list[str]
    dropped: list[str]
    speed_mm_s: float
    speed_deg_s: float
    moves_s: list[float] = field(default_factory=list)
    details: dict[str, Any] = field(default_factory=dict)
    _spread: dict[str, float | int] | None = field(default=None, repr=False, compare=False)

    @property
    def estimated_s(self) -> float:
        """Estimated robot time of all moves (s), settling at each pose included."""
        return float(sum(self.moves_s))

    def remaining_s(self, done: int) -> float:
        """Estimated robot time of the moves still to come after ``done`` poses."""
        return float(sum(self.moves_s[done:]))

    def rotation_spread(self) -> dict[str, float | int]:
        """How the flange rotations between poses are spread (hand-eye needs several axes).

        Over all pairs of up to :data:`SPREAD_POSES` poses taken evenly along the plan (the pairs
        grow with the square of the poses; a laser plan has hundreds).
        """
        if len(self.poses) < 2:
            return {"pairs": 0, "max_pair_angle_deg": 0.0, "median_pair_angle_deg": 0.0, "axis_spread": 0.0, "axis_spread_3d": 0.0}
        if self._spread is not None:
            return self._spread
        d = motion_diversity([self.poses[i] for i in spread_subset(len(self.poses), SPREAD_POSES)])
        self._spread = {
            "pairs": d.n_pairs,
            "max_pair_angle_deg": d.max_pair_angle_deg,
            "median_pair_angle_deg": d.median_pair_angle_deg,
            "axis_spread": d.axis_spread,
            "axis_spread_3d": d.axis_spread_3d,
        }
        return self._spread

    def summary(self, *, with_poses: bool = False) -> dict[str, Any]:
        """The plan as the API, the CLI and the job record show it (mm and degrees)."""
        out: dict[str, Any] = {
            "procedure": self.procedure,
            "poses": len(self.poses),
            "dropped": list(self.dropped),
            "speed_mm_s": self.speed_mm_s,
            "speed_deg_s": self.speed_deg_s,
            "estimated_robot_time_s": self.estimated_s,
            "rotation": self.rotation_spread(),
            "details": self.details,
        }
        if self.poses:
            out["first_pose"] = pose_row(self.poses[0], self.labels[0])
        if with_poses:
            out["pose_list"] = [pose_row(p, lab) for p, lab in zip(self.poses, self.labels)]
        return out


def pose_row(T: Pose, label: str) -> dict[str, Any]:
    """A pose for people: position (mm) and XYZ fixed angles rx, ry, rz (deg, eq. 13)."""
    t, (alpha, beta, gamma) = pose_to_xyz_fixed(T)
    return {
        "label": label,
        "position_mm": [round(float(v), 3) for v in t],
        "xyz_fixed_deg": [round(float(np.degrees(a)), 4) for a in (gamma, beta, alpha)],
    }


def _reach_check(config: CellConfig) -> Any:
    envelope = config.layout.robot

    def check(T_B_H: Pose) -> None:
        problem = envelope.reach_problem(T_B_H)
        if problem is not None:
            raise ValueError(problem)

    return check


def _timed(config: CellConfig, poses: Sequence[Pose], start: Pose | None) -> list[float]:
    c = config.calibration.procedure
    envelope = config.layout.robot
    out = []
    previous = start
    for T in poses:
        out.append(0.0 if previous is None else envelope.move_time_s(previous, T, c.speed_mm_s, c.speed_deg_s))
        previous = T
    return out


def make_plan(config: CellConfig, procedure: str, poses: Sequence[Pose], labels: Sequence[str], dropped: Sequence[str],
          start: Pose | None, details: dict[str, Any]) -> MotionPlan:  # fmt: skip
    c = config.calibration.procedure
    return MotionPlan(
        procedure, [np.asarray(p, dtype=float) for p in poses], list(labels), list(dropped),
        c.speed_mm_s, c.speed_deg_s, _timed(config, poses, start), details,
    )  # fmt: skip


def nominal_T0(config: CellConfig) -> Pose:
    """The workpiece frame where the layout puts the opening's corner."""
    return config.layout.opening.T_B_T_nominal()


def board_spec(board: BoardConfig) -> BoardSpec:
    return BoardSpec(tuple(board.inner_corners), float(board.square_mm))  # type: ignore[arg-type]


def scale_board_at(config: CellConfig) -> tuple[float, float]:
    """The scale board's first inner corner in T0 (mm): the configured place from the shot's aim."""
    aim, at = shot_aim_mm(config), config.calibration.procedure.nine_point.scale_board_on_wall_mm
    return (aim[0] + at[0], aim[1] + at[1])


def board_place(config: CellConfig, board: BoardConfig, at_mm: Sequence[float]) -> dict[str, Any]:
    """Where a board goes, for the prompt: its first inner corner in T0 and in the base frame."""
    T_B_P = pose_in_plane(nominal_T0(config), at_mm)
    return {
        "board": {**board_spec(board).as_dict(), "border_mm": board.border_mm},
        "at_mm": [float(v) for v in at_mm],
        "frame": "T0 (x right, y down from the opening's upper-right corner, on the wall)",
        "first_corner_base_mm": [round(float(v), 1) for v in T_B_P[:3, 3]],
    }


def board_margin_px(config: CellConfig) -> float:
    """How far inside the image the board must stay (px of this camera): calibration.procedure.camera.margin_px is
    stated for a :data:`MARGIN_WIDTH_PX` wide image and scales with layout.camera.width_px (a binned camera's is smaller)."""
    return float(config.calibration.procedure.camera.margin_px) * (config.layout.camera.width_px / MARGIN_WIDTH_PX)


def board_min_views(config: CellConfig, procedure: str) -> tuple[int, str]:
    """The fewest views the procedure's computation accepts, and the setting that says so."""
    if procedure == "hand_eye":
        return config.calibration.procedure.hand_eye.min_views, "calibration.procedure.hand_eye.min_views"
    return config.calibration.procedure.camera.min_views, "calibration.procedure.camera.min_views"


def _board_views(config: CellConfig, n: int) -> PosePlan:
    cc = config.calibration.procedure.camera
    lay = config.layout
    return plan_board_views(
        pose_in_plane(nominal_T0(config), cc.board_on_wall_mm), board_spec(cc.board).outline(cc.board.border_mm),
        lay.camera_mount.T_H_C(), lay.camera.camera_matrix(), lay.camera.dist_coeffs(), (lay.camera.width_px, lay.camera.height_px),
        n, _reach_check(config), distance_mm=cc.distance_mm, tilt_deg=cc.tilt_deg, spin_deg=cc.spin_deg,
        margin_px=board_margin_px(config), seed=0,
    )  # fmt: skip


def plan_board(config: CellConfig, *, views: int | None = None, start: Pose | None = None, procedure: str = "camera") -> MotionPlan:
    """Views of the checkerboard stuck on the wall (camera intrinsics and hand-eye).

    Raises TooFewViews (a PlanError), before anything moves, when fewer views fit than the procedure's computation needs."""
    cc = config.calibration.procedure.camera
    n = views if views is not None else cc.n_views
    if n < 3:
        raise PlanError(f"views: at least 3 board views are needed, got {n}")
    plan = _board_views(config, n)
    need, setting = board_min_views(config, procedure)
    if len(plan.flange_poses) < need:
        raise TooFewViews(procedure, "too_few_views", _too_few_views(config, n, plan, need, setting))
    labels = [f"view_{k:03d}" for k in range(len(plan.flange_poses))]
    details = {"tilt_deg": [min(plan.tilt_deg, default=0.0), max(plan.tilt_deg, default=0.0)],
               "distance_mm": [min(plan.distance_mm, default=0.0), max(plan.distance_mm, default=0.0)],
               "board": board_place(config, cc.board, cc.board_on_wall_mm)}  # fmt: skip
    return make_plan(config, procedure, plan.flange_poses, labels, plan.dropped, start, details)


def _too_few_views(config: CellConfig, n: int, plan: PosePlan, need: int, setting: str) -> str:
    """Why a board plan is short, and the fixes: the --views that plans enough (if any does), the settings."""
    cc, w = config.calibration.procedure.camera, config.layout.camera.width_px
    out_of_view = sum(1 for d in plan.dropped if d.endswith("board leaves the image"))
    # planned(N) = min(N, views that fit among the first 4N + 8 candidates): it grows with N, so bisect
    lo, hi, ask = n + 1, MAX_VIEWS, None
    if n >= MAX_VIEWS or len(_board_views(config, MAX_VIEWS).flange_poses) < need:
        lo = hi + 1  # not even the most views a job may ask for
    while lo <= hi:
        mid = (lo + hi) // 2
        if len(_board_views(config, mid).flange_poses) >= need:
            ask, hi = mid, mid - 1
        else:
            lo = mid + 1
    fit = len(plan.flange_poses)
    if ask is None:
        more = f"no --views up to {MAX_VIEWS} plans enough: "
    else:
        more = (f"run it with --views {ask} (options.views; default calibration.procedure.camera.n_views), which plans "
                f"{len(_board_views(config, ask).flange_poses)}" + (", or " if fit < n else ""))  # fmt: skip
    if fit == n:
        return f"{n} board views are asked for, and the calibration needs at least {need} ({setting}). Nothing moved: {more}"
    return (f"only {fit} of the {n} board views asked for fit ({len(plan.dropped)} candidate view(s) left out: "
            f"{out_of_view} because the board left the image, {len(plan.dropped) - out_of_view} out of the robot's reach), and "
            f"the calibration needs at least {need} ({setting}). Nothing moved: {more}let more views fit: a smaller "
            f"calibration.procedure.camera.margin_px ({cc.margin_px:g} px stated for a {MARGIN_WIDTH_PX} px wide image, "
            f"{board_margin_px(config):g} px on this {w} px wide camera), a larger distance_mm ({cc.distance_mm[0]:g} to "
            f"{cc.distance_mm[1]:g} mm) or a smaller tilt_deg ({cc.tilt_deg[0]:g} to {cc.tilt_deg[1]:g} deg)")  # fmt: skip


def plan_laser(config: CellConfig, *, poses: int | None = None, start: Pose | None = None) -> MotionPlan:
    """The wall shown to the laser from many wrist orientations at several arm stands (laser r, l)."""
    lc = config.calibration.procedure.laser
    lay = config.layout
    r_nom, l_nom = lay.laser_mount.r, lay.laser_mount.l
    T0 = nominal_T0(config)
    R_nom = T0[:3, :3] @ lay.camera_mount.T_H_C()[:3, :3].T
    lo, hi = lay.laser_mount.range_min_mm + lc.range_margin_mm, lay.laser_mount.range_max_mm - lc.range_margin_mm
    n = poses if poses is not None else lc.n_poses
    if n < laser_poses_floor(config):
        field_name = "poses" if poses is not None else "calibration.procedure.laser.n_poses"
        raise PlanError(f"{field_name}: a laser job plans at least {laser_poses_floor(config)} poses ({laser_floor_why(config)}), got {n}")
    plan = plan_laser_poses(
        T0, lc.aim_mm, R_nom, r_nom, l_nom, n, _reach_check(config),
        pivot_H_mm=lc.wrist_in_flange_mm, standoff_mm=lc.standoff_mm, wrist_depths_mm=lc.wrist_depths_mm(),
        tilt_deg=lc.tilt_deg, spin_deg=lc.spin_deg, range_mm=(lo, hi),
        on_wall=lambda xy: lay.opening.on_wall(xy, lc.keep_off_opening_mm),
    )  # fmt: skip
    labels = [f"stand {g} pose {k}" for k, g in enumerate(plan.group)]
    details = {"groups": list(plan.group), "stands": len(set(plan.group)), "aim_mm": list(lc.aim_mm),
               "tilt_deg": list(lc.tilt_deg), "distance_mm": [min(plan.distance_mm, default=0.0), max(plan.distance_mm, default=0.0)],
               "r_nominal": r_nom.tolist(), "l_nominal": l_nom.tolist()}  # fmt: skip
    return make_plan(config, "laser", plan.flange_poses, labels, plan.dropped, start, details)


def laser_poses_floor(config: CellConfig) -> int:
    """The fewest poses a laser job may ask for: the gate's readings and :data:`LASER_SPARE` more."""
    gate = config.calibration.procedure.laser.min_poses
    return gate + math.ceil(gate * LASER_SPARE)


def laser_floor_why(config: CellConfig) -> str:
    """Why :func:`laser_poses_floor` is what it is, naming the setting."""
    gate = config.calibration.procedure.laser.min_poses
    return (f"the calibration needs {gate} usable readings, calibration.procedure.laser.min_poses, and "
            f"{laser_poses_floor(config) - gate} more are planned for readings out of range")  # fmt: skip


def more_laser_poses(config: CellConfig, planned: int, usable: int) -> str:
    """What to ask for after a laser job came back with too few usable readings: ``--poses``, and how many more."""
    if usable <= 0:
        return ("no pose gave a usable reading: check calibration.procedure.laser.aim_mm and the sensor's range "
                "before asking for more poses")  # fmt: skip
    gate = config.calibration.procedure.laser.min_poses
    ask = max(laser_poses_floor(config), math.ceil(planned * gate * (1.0 + LASER_SPARE) / usable))
    return (f"{planned - usable} of the {planned} planned poses gave no usable reading: run it again with "
            f"--poses {ask} (options.poses; {ask - planned} more)")  # fmt: skip


def missing_part(cal: CalibrationSet | None, *parts: str, recipe: str | None = None, named: str | None = None) -> str | None:
    """The first of ``parts`` not usable in ``cal`` (a recipe part: at ``recipe``'s slot), said with the command that
    makes it for recipe ``named`` (None: the first); None when every one is usable."""
    for name in parts:
        if cal is None or not cal.usable(name, recipe):
            return f"{name} must be calibrated first: run `{command(name, named)}`"
    return None


def _need(cal: CalibrationSet | None, procedure: str, *parts: str, **where: str | None) -> CalibrationSet:
    """The set, when the parts the plan needs are usable (:func:`missing_part`); else PlanError."""
    if (missing := missing_part(cal, *parts, **where)) is not None:
        raise PlanError(f"{procedure}: {missing}")
    assert cal is not None
    return cal


def plan_teaching(config: CellConfig, cal: CalibrationSet | None, *, start: Pose | None = None,
                  recipe: str | None = None) -> MotionPlan:  # fmt: skip
    """Laser spots around the opening from the nominal shooting pose (teaching's alignment) of ``config``, the view
    of ``recipe`` when the job names one (its out-of-reach refusal then names the recipe's settings)."""
    cal = _need(cal, "teaching", "camera", "hand_eye", "laser")
    T_H_C = cal.T_H_C()
    r, l = cal.laser_ray()  # noqa: E741
    ac = config.process.align
    T0 = nominal_T0(config)
    shoot = nominal_shooting_pose(T0, T_H_C, config.process.working_distance_mm, shot_aim_mm(config))
    spots = plan_spot_poses(T0, ac.wall_spots_mm(), shoot[:3, :3], r, l, ac.laser_standoff_mm)
    poses, labels, dropped = [], [], []
    check = _reach_check(config)
    for k, X in enumerate(spots):
        try:
            check(X)
        except ValueError as err:
            dropped.append(f"spot {k}: {err}")
            continue
        poses.append(X)
        labels.append(f"spot {k}")
    if dropped:
        raise PlanError("teaching: " + "; ".join(dropped) + f"; move {_wall_and_opening(config, recipe)}")
    details = {"shooting_start": np.asarray(shoot, dtype=float).tolist(), "spots_mm": [list(s) for s in ac.wall_spots_mm()],
               "stops": list(ac.wall_stops()), "hand_guided_installs": config.calibration.procedure.teach.hand_guided_installs}  # fmt: skip
    return make_plan(config, "teaching", poses, labels, dropped, start, details)


def _wall_and_opening(config: CellConfig, recipe: str | None) -> str:
    """The settings that place teaching's wall readings and the opening: a recipe's own when the job names one."""
    setting = config.process.align.wall_setting()
    index = next((k for k, r in enumerate(config.process.recipes) if r.name == recipe), None)
    if index is None:
        return f"{setting} or the layout's opening"
    own = f"process.recipes[{index}] ({recipe}): {setting.removeprefix('process.')}"
    return (f"{own} or opening.corner_position_mm (the recipe's [process.recipes.align] and [process.recipes.opening]; "
            f"where it sets none, the cell's {setting} and [layout.opening])")


def plan_nine_point(
    config: CellConfig, cal: CalibrationSet | None, *, start: Pose | None = None, recipe: str | None = None
) -> MotionPlan:
    """A 3 x 3 grid of camera shifts in the wall plane about the taught shooting pose (of ``recipe``; None: the first)."""
    slot = None if cal is None else parts_of(cal, recipe, config.default_recipe)
    cal = _need(cal, "pixel_map", "camera", "teaching", recipe=slot, named=recipe_named(slot, recipe, config.default_recipe))
    taught = cal.taught(slot)
    npc = config.calibration.procedure.nine_point
    offsets = nine_point_offsets(npc.step_mm)
    targets = nine_point_targets(taught.C_Pos_0, taught.T0, offsets)
    labels = [f"offset ({o[0]:+.0f}, {o[1]:+.0f}) mm" for o in offsets]
    details = {"step_mm": npc.step_mm, "offsets_mm": offsets.tolist(),
               "scale_board": board_place(config, npc.scale_board, scale_board_at(config))}  # fmt: skip
    return make_plan(config, "pixel_map", targets, labels, [], start, details)


def spread_subset(count: int, take: int) -> list[int]:
    """``take`` indices spread evenly over ``range(count)`` (all of them if there are fewer)."""
    if take >= count:
        return list(range(count))
    return sorted({int(round(k * (count - 1) / max(take - 1, 1))) for k in range(take)})
