"""The commissioning procedures: collect a calibration dataset on the cell, through the ports only.

Each procedure plans from the cell's nominal layout (and the calibration set where it builds on
it), asks the engineer for what a robot cannot do (the car body in place, the board on the wall,
the glass guided into the opening), shows its plan and waits for the engineer to confirm that
the first pose is clear, then moves at the reduced speed and records every sample with the pose
the controller reports after the move. The dataset is then computed exactly as a saved one is
(:mod:`cellctl.calibration.compute`). The same code runs on a real cell and in the simulated one.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.calibration.calibration_set import CalibrationSet, parts_of, recipe_named
from cellctl.calibration.collect import move_and_report
from cellctl.calibration.collect import move_or_skip as collect_move_or_skip
from cellctl.calibration.compute import Outcome, compute_camera, compute_hand_eye, compute_laser, detect_views
from cellctl.calibration.compute_recipe import align_for_teaching, compute_nine_point, compute_teaching
from cellctl.calibration.dataset import Dataset, pose_list
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.taught_shot import taught_shot
from cellctl.commissioning.camera_grab import grab
from cellctl.commissioning.context import DatasetDraft, JobContext
from cellctl.commissioning.plans import (
    MotionPlan,
    board_place,
    missing_part,
    more_laser_poses,
    nominal_T0,
    plan_board,
    plan_laser,
    plan_nine_point,
    plan_teaching,
    pose_row,
    scale_board_at,
)
from cellctl.commissioning.prompts import PromptKind
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import Pose, mean_pose
from cellctl.ports import DeviceRejected, LaserStatus


class PoseRefused(Exception):
    """The robot refused one planned pose; the procedure drops it with the reason and goes on."""


async def move_to(ctx: JobContext, target: Pose) -> Pose:
    """Move at the procedure's speed and return the flange pose the controller reports there."""
    try:
        return await move_and_report(ctx.devices.robot, target, ctx.motion)
    except DeviceRejected as err:
        raise PoseRefused(str(err)) from None


async def move_or_skip(
    ctx: JobContext, draft: DatasetDraft, target: Pose, label: str, step: tuple[int, int] | None,
    refused: str = "the robot refused the pose",
) -> Pose | None:  # fmt: skip
    """``move_to``, or None when the robot refuses: the draft's ``skipped`` says why (and the progress, at ``step``)."""
    skipped = draft.manifest["skipped"]
    return await collect_move_or_skip(ctx.devices.robot, target, ctx.motion, skipped, label, step, ctx.progress, refused)


async def current_pose(ctx: JobContext) -> Pose | None:
    """Where the robot stands (for the first move's time), or None if it does not answer."""
    try:
        return (await ctx.devices.robot.read_pose(timeout_s=ctx.motion.read_timeout_s)).to_matrix()
    except Exception:  # noqa: BLE001 - only the time estimate of the first move needs it
        return None


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f} min" if seconds >= 90 else f"{seconds:.0f} s"


async def confirm_start(ctx: JobContext, plan: MotionPlan, what: str) -> None:
    """Show the plan and wait until the engineer confirms the way to the first pose is clear."""
    await asyncio.to_thread(plan.rotation_spread)  # the one costly figure of the summary, off the event loop
    ctx.show_plan(plan)
    if not plan.poses:
        raise CalibrationRefused(plan.procedure, "unreachable", "no planned pose is reachable: " + "; ".join(plan.dropped[:5]))
    first = pose_row(plan.poses[0], plan.labels[0])
    x, y, z = first["position_mm"]
    await ctx.ask(
        PromptKind.CONFIRM_START,
        f"The robot will now visit {len(plan.poses)} poses for {what} at up to {plan.speed_mm_s:g} mm/s "
        f"(about {_minutes(plan.estimated_s)} of robot time), first to ({x:.0f}, {y:.0f}, {z:.0f}) mm. "
        "Check that the path from where it stands to there is clear, then confirm.",
        details={"first_pose": first, "poses": len(plan.poses), "estimated_robot_time_s": plan.estimated_s,
                 "dropped": len(plan.dropped), "speed_mm_s": plan.speed_mm_s},
    )  # fmt: skip


async def car_body_in_place(ctx: JobContext, text: str, *, recipe: str | None = None) -> None:
    """Ask for the car body at its nominal place (``recipe``: a reference car body of that recipe's window)."""
    opening = ctx.config.layout.opening
    details: dict[str, Any] = {"nominal_corner_base_mm": list(opening.corner_position_mm), "nominal": True}
    if recipe is not None:
        details |= {"recipe": recipe, "opening_mm": [opening.width_mm, opening.height_mm, opening.corner_radius_mm]}
        text = (f"Recipe {recipe} ({opening.width_mm:g} x {opening.height_mm:g} mm opening, corner radius "
                f"{opening.corner_radius_mm:g} mm): {text}")  # fmt: skip
    await ctx.ask(PromptKind.CAR_BODY, text, details=details)


def board_recipe(config: CellConfig) -> str:
    """The recipe whose car body the board views and the laser calibration stand at: the first, whose opening
    ``[layout.opening]`` is (a job's configuration is that recipe's view)."""
    return config.default_recipe


def _opening(config: CellConfig, recipe: str) -> str:
    """How a prompt names the opening of ``recipe`` (``config``: that recipe's view)."""
    o = config.layout.opening
    return f"recipe {recipe}'s {o.width_mm:g} x {o.height_mm:g} mm opening"


def wall_offset(x_mm: float, y_mm: float) -> str:
    """A place on the wall in T0 (x right, y down, mm) as a person measures it: distances, the direction by the sign."""
    return f"{abs(x_mm):g} mm {'right' if x_mm >= 0 else 'left'} and {abs(y_mm):g} mm {'down' if y_mm >= 0 else 'up'}"


def board_hint(err: CalibrationRefused, config: CellConfig) -> CalibrationRefused:
    """A board_not_found refusal with the check of the car body the board is placed beside (others unchanged)."""
    if err.reason != "board_not_found":
        return err
    recipe = board_recipe(config)
    return CalibrationRefused(err.part, err.reason, f"{err.detail}; is the car body of recipe {recipe} standing in the "
                              f"cell? The board goes beside {_opening(config, recipe)}: bring that car body in and run the "
                              "job again")  # fmt: skip


async def place_board(ctx: JobContext, place: dict[str, Any], name: str, recipe: str) -> float:
    """Ask for the board on the wall beside ``recipe``'s opening; returns the square size the engineer measured (mm)."""
    b = place["board"]
    x, y = place["at_mm"]
    cols, rows = b["inner_corners"]
    answer = await ctx.ask(
        PromptKind.PLACE_BOARD,
        f"Fix the {name} ({cols} x {rows} inner corners, {b['square_mm']:g} mm squares) flat on the car-body wall with "
        f"its first inner corner {wall_offset(x, y)} of the upper-right corner of "
        f"{_opening(ctx.config, recipe)}, rows along the top edge. Measure the square size across the whole board and "
        "give it in mm (confirm keeps the nominal size).",
        details=place | {"recipe": recipe},
        value_label="measured square size (mm)",
        default=float(b["square_mm"]),
    )
    return float(answer.value if answer.value is not None else b["square_mm"])


async def remove_board(ctx: JobContext, name: str) -> None:
    await ctx.ask(PromptKind.REMOVE_BOARD, f"Take the {name} off the wall, then confirm.")


# -- camera intrinsics and hand-eye: views of the board ------------------------------------------


async def collect_board_views(ctx: JobContext, *, views: int | None = None, procedure: str = "camera") -> Dataset:
    """Stick the board on the wall, view it from the planned poses, take it off again."""
    plan = await asyncio.to_thread(plan_board, ctx.config, views=views, start=await current_pose(ctx), procedure=procedure)
    cc = ctx.config.calibration.procedure.camera
    lens = ctx.config.layout.camera
    recipe = board_recipe(ctx.config)
    await car_body_in_place(ctx, "A car body stands clamped in the cell, its opening near the nominal place; confirm.",
                            recipe=recipe)  # fmt: skip
    square = await place_board(ctx, plan.details["board"], "checkerboard", recipe)
    draft = ctx.begin(
        "board_views",
        board={"inner_corners": list(cc.board.inner_corners), "square_mm": square, "border_mm": cc.board.border_mm,
               "on_wall_mm": list(cc.board_on_wall_mm)},
        image_size=[lens.width_px, lens.height_px],
        plan=plan.summary(),
        views=[],
        skipped=[],
    )  # fmt: skip
    await confirm_start(ctx, plan, "the board views")
    n = len(plan.poses)
    for k, (X, name) in enumerate(zip(plan.poses, plan.labels)):
        reported = await move_or_skip(ctx, draft, X, name, (k + 1, n))
        if reported is None:
            continue
        frame = await grab(ctx, procedure)
        draft.images[f"{name}.png"] = frame.image
        draft.manifest["views"].append({"name": name, "image": f"{name}.png", "T_B_H": pose_list(reported), "T_B_H_target": pose_list(X)})
        ctx.progress(k + 1, n, f"{name}: frame {frame.frame_id}")
    await remove_board(ctx, "checkerboard")
    return await ctx.finish()


# -- laser ---------------------------------------------------------------------------------------


async def collect_laser_plane(ctx: JobContext, *, poses: int | None = None) -> Dataset:
    """Show a plain patch of the wall to the laser from many wrist orientations at several arm stands."""
    plan = await asyncio.to_thread(plan_laser, ctx.config, poses=poses, start=await current_pose(ctx))
    head = ctx.config.layout.laser_mount
    aim = ctx.config.calibration.procedure.laser.aim_mm
    await car_body_in_place(
        ctx,
        f"A car body stands clamped in the cell; the laser reads its plain wall around {wall_offset(*aim)} of the "
        "opening's upper-right corner (no seal, label or edge within 300 mm of it). Confirm.",
        recipe=board_recipe(ctx.config),
    )
    draft = ctx.begin(
        "laser_plane",
        readings=[],
        sensor_range_mm=[head.range_min_mm, head.range_max_mm],
        r_nominal=plan.details["r_nominal"],
        l_nominal=plan.details["l_nominal"],
        plan=plan.summary(),
        skipped=[],
    )
    await confirm_start(ctx, plan, "the laser calibration")
    groups = plan.details["groups"]
    n = len(plan.poses)
    for k, (X, g) in enumerate(zip(plan.poses, groups)):
        reported = await move_or_skip(ctx, draft, X, f"pose {k}", (k + 1, n), refused="the robot refused it")
        if reported is None:
            continue
        reading = await ctx.devices.laser.read(timeout_s=ctx.motion.read_timeout_s)
        draft.manifest["readings"].append({
            "T_B_H": pose_list(reported), "T_B_H_target": pose_list(X), "group": int(g), "status": reading.status.value,
            "distance_mm": reading.distance_mm if reading.status is LaserStatus.OK else None,
        })  # fmt: skip
        ctx.progress(k + 1, n, f"pose {k}: {reading.status.value}")
    return await ctx.finish()


# -- teaching ------------------------------------------------------------------------------------


def _need(cal: CalibrationSet | None, part: str, *names: str, **where: str | None) -> CalibrationSet:
    """The set, when the parts ``part`` builds on are usable (:func:`missing_part`); else refused."""
    if (missing := missing_part(cal, *names, **where)) is not None:
        raise CalibrationRefused(part, "missing_input", missing)
    assert cal is not None
    return cal


async def collect_teaching(ctx: JobContext, *, recipe: str | None = None) -> Dataset:
    """Align at the reference car body (of ``recipe``; None: the first), take the template image, record the hand-guided installs."""
    cal = _need(ctx.calibration, "teaching", "camera", "hand_eye", "laser")
    config = ctx.config
    plan = await asyncio.to_thread(plan_teaching, config, cal, start=await current_pose(ctx), recipe=recipe)
    head = config.layout.laser_mount
    tc = config.calibration.procedure.teach
    shoot = plan.details["shooting_start"]
    stops = plan.details["stops"]  # on the move: the spots at the sweep's corners give the plane's offset, as in the cycle
    await car_body_in_place(
        ctx,
        "Bring the reference car body into the cell and clamp it at its nominal place: its opening defines the "
        "workpiece frame T0 every cycle is corrected to. Confirm when it stands still.",
        recipe=recipe or config.default_recipe,
    )
    draft = ctx.begin(
        "teaching",
        spots=[],
        T0_nominal=pose_list(nominal_T0(config)),
        sensor_range_mm=[head.range_min_mm, head.range_max_mm],
        operator={"kind": "hand guiding", "installs": tc.hand_guided_installs},
        g_Pos_0_installs=[],
        plan=plan.summary(),
        recipe=recipe or config.default_recipe,
        wall_read={"mode": config.process.align.mode, "spots_mm": plan.details["spots_mm"]},  # the cycle must read it so
        shot=taught_shot(config),  # the settings the shot stands on (a recompute checks them)
    )
    await confirm_start(ctx, plan, "the teaching alignment")
    spots_H, spots_d = [], []
    n_steps = len(plan.poses) + 1 + tc.hand_guided_installs
    for k, X in enumerate(plan.poses):
        try:
            reported = await move_to(ctx, X)
        except PoseRefused as err:
            raise CalibrationRefused("teaching", "unreachable", f"laser spot {k}: {err}") from None
        reading = await ctx.devices.laser.read(timeout_s=ctx.motion.read_timeout_s)
        if reading.status is not LaserStatus.OK or reading.distance_mm is None:
            raise CalibrationRefused(
                "teaching", "alignment",
                f"laser spot {k} gave no distance ({reading.status.value}); move {config.process.align.wall_setting()} onto "
                "the wall and within the sensor's range",
            )  # fmt: skip
        spots_H.append(reported)
        spots_d.append(float(reading.distance_mm))
        draft.manifest["spots"].append(
            {"T_B_H": pose_list(reported), "distance_mm": float(reading.distance_mm)} | ({"stop": True} if k in stops else {})
        )
        ctx.progress(k + 1, n_steps, f"laser spot {k}: {reading.distance_mm:.3f} mm")
    start = np.asarray(shoot, dtype=float)
    draft.manifest["shooting_start"] = pose_list(start)
    align = await asyncio.to_thread(
        align_for_teaching, np.array(spots_H), np.array(spots_d), stops, cal, config, start, (head.range_min_mm, head.range_max_mm)
    )
    C_Pos_0 = await move_to(ctx, align.T_B_H_aligned)
    frame = await grab(ctx, "teaching")
    draft.manifest["C_Pos_0"] = pose_list(C_Pos_0)
    draft.manifest["shooting_image"] = "template.png"
    draft.images["template.png"] = frame.image
    ctx.progress(len(plan.poses) + 1, n_steps, "template image taken at the aligned shooting pose C_Pos_0")
    installs = []
    ctx.robot_left = _glass_in_opening("may hold the glass in or at the car body's opening (the job ended during the "
                                       "hand-guided installs)", C_Pos_0)  # fmt: skip
    for k in range(tc.hand_guided_installs):
        again = " Take the glass out of the opening and guide it in again from outside." if k else ""
        await ctx.ask(
            PromptKind.GUIDE_INSTALL,
            f"Install {k + 1} of {tc.hand_guided_installs}: jog or lead the robot until the glass sits in the opening as "
            f"it must be installed, then confirm; the robot's pose is read then.{again}",
            details={"index": k + 1, "count": tc.hand_guided_installs, "shooting_pose": pose_row(C_Pos_0, "C_Pos_0")},
        )
        pose = (await ctx.devices.robot.read_pose(timeout_s=ctx.motion.read_timeout_s)).to_matrix()
        installs.append(pose)
        x, y, z = pose[:3, 3]
        ctx.robot_left = _glass_in_opening(f"holds the glass in the car body's opening (flange at x {x:.1f}, y {y:.1f}, "
                                           f"z {z:.1f} mm at install {k + 1})", C_Pos_0)  # fmt: skip
        draft.manifest["g_Pos_0_installs"].append(pose_list(pose))
        ctx.progress(len(plan.poses) + 2 + k, n_steps, f"hand-guided install {k + 1} of {tc.hand_guided_installs} recorded")
    g_Pos_0 = mean_pose(np.array(installs))
    draft.manifest["g_Pos_0"] = pose_list(g_Pos_0)
    await ctx.ask(
        PromptKind.RETREAT,
        "Jog the robot with the glass back out of the opening to a clear pose (e.g. the shooting pose), then confirm.",
        details={"clear_pose": pose_row(C_Pos_0, "C_Pos_0")},
    )
    ctx.robot_left = None  # out of the opening: the robot may move on
    return await ctx.finish({"g_Pos_0": g_Pos_0})


def _glass_in_opening(where: str, clear: Pose) -> str:
    """A teaching job's end while the glass may stand in the opening: where the robot was left and what to do."""
    x, y, z = clear[:3, 3]
    return (f"The robot {where}: jog it with the glass back out of the opening to a clear pose (e.g. the shooting pose "
            f"C_Pos_0 at x {x:.1f}, y {y:.1f}, z {z:.1f} mm) before any job or cycle moves it")  # fmt: skip


# -- nine-point map and pixel scale ----------------------------------------------------------------


async def collect_nine_point(ctx: JobContext, *, recipe: str | None = None) -> Dataset:
    """Nine images of the window corner from the taught pose (of ``recipe``; None: the first) shifted in the wall plane, then the scale board."""
    recipe = recipe or ctx.config.default_recipe
    slot = None if ctx.calibration is None else parts_of(ctx.calibration, recipe, ctx.config.default_recipe)
    cal = _need(ctx.calibration, "pixel_map", "camera", "teaching", recipe=slot,
                named=recipe_named(slot, recipe, ctx.config.default_recipe))
    plan = await asyncio.to_thread(plan_nine_point, ctx.config, cal, start=await current_pose(ctx), recipe=recipe)
    taught = cal.taught(slot)
    npc = ctx.config.calibration.procedure.nine_point
    await car_body_in_place(
        ctx, "The car body taught with (or one clamped at the same place) stands in the cell; its window corner must be "
        "in view from the taught shooting pose. Confirm.", recipe=recipe,
    )  # fmt: skip
    draft = ctx.begin(
        "nine_point",
        recipe=recipe,
        views=[],
        C_Pos_0=pose_list(taught.C_Pos_0),
        T0=pose_list(taught.T0),
        scale_image="scale.png",
        scale_board={"inner_corners": list(npc.scale_board.inner_corners), "square_mm": npc.scale_board.square_mm,
                     "on_wall_mm": list(scale_board_at(ctx.config))},
        plan=plan.summary(),
    )  # fmt: skip
    await confirm_start(ctx, plan, "the nine-point map")
    offsets = plan.details["offsets_mm"]
    n = len(plan.poses) + 1
    for k, (X, o) in enumerate(zip(plan.poses, offsets)):
        name = f"offset_{k:03d}"
        try:
            reported = await move_to(ctx, X)
        except PoseRefused as err:
            raise CalibrationRefused("pixel_map", "unreachable", f"{name}: {err}") from None
        frame = await grab(ctx, "pixel_map")
        draft.images[f"{name}.png"] = frame.image
        draft.manifest["views"].append({"name": name, "image": f"{name}.png", "T_B_H": pose_list(reported), "offset_target_mm": list(o)})
        ctx.progress(k + 1, n, f"{name}: frame {frame.frame_id}")
    await move_to(ctx, taught.C_Pos_0)
    place = board_place(ctx.config, npc.scale_board, scale_board_at(ctx.config))  # where the camera looks
    draft.manifest["scale_board"]["square_mm"] = await place_board(ctx, place, "scale checkerboard", recipe)
    frame = await grab(ctx, "pixel_map")
    draft.images["scale.png"] = frame.image
    ctx.progress(n, n, "scale board image taken")
    await remove_board(ctx, "scale checkerboard")
    return await ctx.finish()


# -- the table ------------------------------------------------------------------------------------

# (config, the set in use, the job's options, the robot's pose, the calibration store folder) -> the plan
Plan = Callable[[CellConfig, "CalibrationSet | None", dict[str, Any], "Pose | None", "Path | None"], MotionPlan]
Collect = Callable[..., Awaitable[Dataset]]
Compute = Callable[[Dataset, "CalibrationSet | None", CellConfig], Outcome]


@dataclass(frozen=True)
class Procedure:
    """One part's calibration: the dataset kind it collects, how, and how it is computed.

    ``options`` names the collection's options (e.g. ``views``) that the CLI and REST may set;
    :meth:`option_names` adds ``store`` and hand-eye's ``method``.
    """

    part: str
    kind: str
    method: str
    needs: tuple[str, ...]
    plan: Plan  # what the collection will move through (the dry run), from the config, the set, its options
    collect: Collect
    compute: Compute
    options: tuple[str, ...] = ()
    records_part: bool = True  # False: a check that never changes the calibration set (verify)

    def option_names(self) -> list[str]:
        """Every option a job of this procedure takes."""
        return (["store"] if self.records_part else []) + list(self.options) + (["method"] if self.part == "hand_eye" else [])


async def _board_camera(ctx: JobContext, *, views: int | None = None) -> Dataset:
    return await collect_board_views(ctx, views=views, procedure="camera")


async def _board_hand_eye(ctx: JobContext, *, views: int | None = None) -> Dataset:
    return await collect_board_views(ctx, views=views, procedure="hand_eye")


def _camera(ds: Dataset, cal: CalibrationSet | None, cfg: CellConfig) -> Outcome:
    try:
        return compute_camera(ds, cfg)
    except CalibrationRefused as err:
        raise board_hint(err, cfg) from None


def _hand_eye(ds: Dataset, cal: CalibrationSet | None, cfg: CellConfig) -> Outcome:
    try:
        return compute_hand_eye(ds, cal, cfg, detect_views(ds, cfg.calibration.procedure.camera.refine))
    except CalibrationRefused as err:
        raise board_hint(err, cfg) from None


def _laser(ds: Dataset, cal: CalibrationSet | None, cfg: CellConfig) -> Outcome:
    """compute_laser; a refusal for too few readings also says how many poses to ask for (``--poses``)."""
    try:
        return compute_laser(ds, cfg)
    except CalibrationRefused as err:
        if err.reason != "too_few_poses":
            raise
        rows = ds.manifest["readings"]
        usable = sum(1 for r in rows if r["status"] == "ok" and r["distance_mm"] is not None)
        planned = int((ds.manifest.get("plan") or {}).get("poses", len(rows)))
        raise CalibrationRefused("laser", err.reason, f"{err.detail}; {more_laser_poses(cfg, planned, usable)}") from None


PROCEDURES: dict[str, Procedure] = {
    "camera": Procedure(
        "camera", "board_views", "zhang", (),
        lambda cfg, cal, o, start, root: plan_board(cfg, views=o.get("views"), start=start, procedure="camera"),
        _board_camera, _camera, ("views",),
    ),
    "hand_eye": Procedure(
        "hand_eye", "board_views", "tsai", ("camera",),
        lambda cfg, cal, o, start, root: plan_board(cfg, views=o.get("views"), start=start, procedure="hand_eye"),
        _board_hand_eye, _hand_eye, ("views",),
    ),
    "laser": Procedure(
        "laser", "laser_plane", "plane constraint", (),
        lambda cfg, cal, o, start, root: plan_laser(cfg, poses=o.get("poses"), start=start),
        collect_laser_plane, _laser, ("poses",),
    ),
    "teaching": Procedure(
        "teaching", "teaching", "teaching", ("camera", "hand_eye", "laser"),
        lambda cfg, cal, o, start, root: plan_teaching(cfg, cal, start=start, recipe=o.get("recipe")),
        collect_teaching, compute_teaching, ("recipe",),
    ),
    "pixel_map": Procedure(
        "pixel_map", "nine_point", "nine-point", ("camera", "teaching"),
        lambda cfg, cal, o, start, root: plan_nine_point(cfg, cal, start=start, recipe=o.get("recipe")), collect_nine_point,
        compute_nine_point, ("recipe",),
    ),
}  # fmt: skip
# The order a cell is commissioned in: each part only needs parts before it.
ORDER = ("camera", "hand_eye", "laser", "teaching", "pixel_map")

