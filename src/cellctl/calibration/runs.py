"""Calibration runs on the cell: plan, collect through the ports, save the dataset; and record results.

Each ``collect_*`` drives the simulated cell (:class:`cellctl.calibration.twin.TwinCell`: its
robot, laser and camera through the ports, and the engineer's hands for placing targets and
guiding the robot) and writes a dataset folder; the computation is then the same as offline
(cellctl.calibration.compute). Plans use only nominal knowledge: the layout's nominal window
corner, the CAD mounting of camera and laser, the datasheet lens, and the robot's reach check.
The simulator's truth is written into the manifest under ``twin_truth`` for the report and is
never read by the computation.
"""

from __future__ import annotations

import platform
from datetime import datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import scipy

import cellctl
from cellctl.align import AlignmentError, compute_alignment, plan_spot_poses
from cellctl.calibration.calibration_set import CalibrationSet, CalibrationStore, make_part
from cellctl.calibration.collect import MotionSettings, Progress, collect_distances, collect_images, move_and_report
from cellctl.calibration.compute import Outcome
from cellctl.calibration.dataset import Dataset, default_dataset_dir, pose_list, write_dataset
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.pixel_map import nine_point_offsets, nine_point_targets
from cellctl.calibration.poses import plan_board_views, plan_laser_poses
from cellctl.calibration.teach import nominal_shooting_pose
from cellctl.calibration.twin import TwinCell, board_spec
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import mean_pose
from cellctl.ports import LaserStatus
from cellctl.sim.targets import Checkerboard, place_on_world_plane


def _quiet(done: int, total: int, what: str) -> None:
    return None


def motion_settings(config: CellConfig) -> MotionSettings:
    c = config.calibration.procedure
    return MotionSettings(c.speed_mm_s, c.speed_deg_s, c.move_timeout_s, c.read_timeout_s, c.grab_timeout_s)


def software() -> dict[str, str]:
    return {
        "cellctl": getattr(cellctl, "__version__", "unknown"),
        "opencv": cv2.__version__,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "python": platform.python_version(),
    }


def _nominal_T0(config: CellConfig) -> np.ndarray:
    return config.sim.world.T_B_T_nominal()


def _on_wall(config: CellConfig, margin: float) -> Any:
    w = config.sim.world

    def check(xy: np.ndarray) -> bool:
        x, y = float(xy[0]), float(xy[1])
        return x > margin or y < -margin or x < -w.opening_width_mm - margin or y > w.opening_height_mm + margin

    return check


# -- board views (camera intrinsics, hand-eye) ---------------------------------------------------


async def collect_board_views(
    twin: TwinCell, config: CellConfig, dest: Path, *, n_views: int | None = None, seed: int = 0, progress: Progress = _quiet
) -> Dataset:
    """Stick the board on the wall, view it from a planned set of poses, save the dataset."""
    cc = config.calibration.procedure.camera
    cam = config.sim.camera
    K_nom, D_nom = cam.intrinsics.camera_matrix(), cam.intrinsics.dist_coeffs()
    T_H_C_nom = cam.hand_eye.T_H_C()
    size = (cam.intrinsics.width_px, cam.intrinsics.height_px)
    plate = Checkerboard(inner_corners=cc.board.inner_corners, square_mm=cc.board.square_mm, border_mm=cc.board.border_mm)
    (cx, cy), (hx, hy) = plate.plate_rect()
    outline = np.array([[cx - hx, cy - hy, 0.0], [cx + hx, cy - hy, 0.0], [cx + hx, cy + hy, 0.0], [cx - hx, cy + hy, 0.0]])
    T_B_P_nominal = place_on_world_plane(_nominal_T0(config), cc.board_on_wall_mm)
    n = n_views if n_views is not None else cc.n_views
    plan = plan_board_views(
        T_B_P_nominal, outline, T_H_C_nom, K_nom, D_nom, size, n, twin.cell.robot_model.check_reach,
        distance_mm=cc.distance_mm, tilt_deg=cc.tilt_deg, spin_deg=cc.spin_deg, margin_px=cc.margin_px, seed=seed,
    )
    placed = twin.stick_board(cc.board, cc.board_on_wall_mm)
    try:
        samples = await collect_images(twin.robot, twin.camera, plan.flange_poses, motion_settings(config), progress=progress)
    finally:
        twin.remove_targets()
    i = cam.intrinsics
    manifest = {
        "source": twin.describe(),
        "board": {**board_spec(cc.board).as_dict(), "border_mm": cc.board.border_mm, "on_wall_mm": list(cc.board_on_wall_mm)},
        "image_size": list(size),
        "views": [
            {"name": nm, "image": f"{nm}.png", "T_B_H": pose_list(h), "T_B_H_target": pose_list(t)}
            for nm, h, t in zip(samples.names, samples.T_B_H, samples.targets)
        ],
        "plan": {"tilt_deg": plan.tilt_deg, "spin_deg": plan.spin_deg, "distance_mm": plan.distance_mm, "dropped": plan.dropped},
        "skipped": samples.skipped,
        "twin_truth": {
            "intrinsics": {"fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy, "dist": list(i.dist_coeffs())},
            "T_H_C": pose_list(twin.cell.T_H_C),
            "T_B_P": pose_list(placed.T_B_P),
        },
    }
    return write_dataset(dest, "board_views", manifest, {f"{nm}.png": img for nm, img in zip(samples.names, samples.images)})


# -- laser --------------------------------------------------------------------------------------


def cad_laser(config: CellConfig) -> tuple[np.ndarray, np.ndarray]:
    """The laser mounting as a drawing gives it: the configured ray rounded to 1 mm and 0.01."""
    r = np.round(config.sim.laser.r, 0)
    l = np.round(config.sim.laser.l, 2)  # noqa: E741
    return r, l / np.linalg.norm(l)


async def collect_laser_plane(
    twin: TwinCell, config: CellConfig, dest: Path, *, n_poses: int | None = None, progress: Progress = _quiet
) -> Dataset:
    """Show the wall to the laser from many wrist orientations; save poses and distances."""
    lc = config.calibration.procedure.laser
    laser = config.sim.laser
    r_nom, l_nom = cad_laser(config)
    T0 = _nominal_T0(config)
    R_nom = T0[:3, :3] @ config.sim.camera.hand_eye.T_H_C()[:3, :3].T
    lo, hi = laser.range_min_mm + lc.range_margin_mm, laser.range_max_mm - lc.range_margin_mm
    plan = plan_laser_poses(
        T0, lc.aim_mm, R_nom, r_nom, l_nom, n_poses if n_poses is not None else lc.n_poses, twin.cell.robot_model.check_reach,
        pivot_H_mm=lc.wrist_in_flange_mm, standoff_mm=lc.standoff_mm, wrist_depths_mm=lc.wrist_depths_mm(),
        tilt_deg=lc.tilt_deg, spin_deg=lc.spin_deg, range_mm=(lo, hi), on_wall=_on_wall(config, lc.keep_off_opening_mm),
    )
    samples = await collect_distances(twin.robot, twin.laser, plan.flange_poses, plan.group, motion_settings(config), progress=progress)
    manifest = {
        "source": twin.describe(),
        "readings": [
            {"T_B_H": pose_list(h), "distance_mm": dist, "status": st, "group": g}
            for h, dist, st, g in zip(samples.T_B_H, samples.distances_mm, samples.statuses, samples.groups)
        ],
        "sensor_range_mm": [laser.range_min_mm, laser.range_max_mm],
        "r_nominal": r_nom.tolist(),
        "l_nominal": l_nom.tolist(),
        "plan": {"tilt_deg": plan.tilt_deg, "spin_deg": plan.spin_deg, "distance_mm": plan.distance_mm, "dropped": plan.dropped},
        "skipped": samples.skipped,
        "twin_truth": {"r": twin.cell.laser_model.r.tolist(), "l": twin.cell.laser_model.l.tolist()},
    }
    return write_dataset(dest, "laser_plane", manifest, {})


# -- teaching -----------------------------------------------------------------------------------


async def collect_teaching(
    twin: TwinCell, config: CellConfig, cal: CalibrationSet, dest: Path, *, progress: Progress = _quiet
) -> Dataset:
    """Align at the standing car body, take the template image, record the hand-guided install pose."""
    motion = motion_settings(config)
    T_H_C = cal.T_H_C()
    r, l = cal.laser_ray()  # noqa: E741
    laser = config.sim.laser
    ac = config.process.align
    T0_nom = _nominal_T0(config)
    start = nominal_shooting_pose(T0_nom, T_H_C, config.process.working_distance_mm)
    spots = plan_spot_poses(T0_nom, ac.spots_mm, start[:3, :3], r, l, ac.laser_standoff_mm)
    samples = await collect_distances(twin.robot, twin.laser, list(spots), [0] * len(spots), motion, progress=progress)
    bad = [k for k, s in enumerate(samples.statuses) if s != LaserStatus.OK.value]
    if bad or samples.skipped:
        raise CalibrationRefused(
            "teaching", "alignment",
            f"laser spots {bad} gave no distance ({[samples.statuses[k] for k in bad]}) {samples.skipped}; "
            "move process.align.spots_mm onto the wall and within the sensor's range",
        )
    try:
        align = compute_alignment(
            np.array(samples.T_B_H), np.array(samples.distances_mm, dtype=float), r, l, T_H_C,
            config.process.working_distance_mm, T_B_H_current=start,
            range_mm=(laser.range_min_mm, laser.range_max_mm), inlier_threshold_mm=ac.inlier_threshold_mm,
            max_rms_mm=ac.max_rms_mm, min_collinearity=ac.min_collinearity,
        )
    except AlignmentError as err:
        raise CalibrationRefused("teaching", "alignment", str(err)) from None
    C_Pos_0 = await move_and_report(twin.robot, align.T_B_H_aligned, motion)
    frame = await twin.camera.grab(timeout_s=motion.grab_timeout_s)
    C_Pos_0_true = twin.cell.true_flange_pose()
    progress(1, 2, "template image taken at the aligned shooting pose")
    tc = config.calibration.procedure.teach
    installs = []
    for k in range(tc.hand_guided_installs):
        guided = twin.operator_install_pose(tc.hand_guiding_position_mm, tc.hand_guiding_orientation_deg)
        installs.append(await move_and_report(twin.robot, guided, motion))
        progress(1, 2, f"hand-guided install {k + 1} of {tc.hand_guided_installs} recorded")
    # The robot goes to the mean, where the twin scores the taught install pose.
    g_Pos_0 = await move_and_report(twin.robot, mean_pose(installs), motion)
    progress(2, 2, "install pose taught: the mean of the hand-guided installs")
    manifest = {
        "source": twin.describe(),
        "spots": [{"T_B_H": pose_list(h), "distance_mm": d} for h, d in zip(samples.T_B_H, samples.distances_mm)],
        "shooting_start": pose_list(start),
        "C_Pos_0": pose_list(C_Pos_0),
        "shooting_image": "template.png",
        "g_Pos_0_installs": [pose_list(h) for h in installs],
        "g_Pos_0": pose_list(g_Pos_0),
        "T0_nominal": pose_list(T0_nom),
        "sensor_range_mm": [laser.range_min_mm, laser.range_max_mm],
        "operator": {
            "kind": "simulated hand guiding",
            "position_sigma_mm": tc.hand_guiding_position_mm,
            "orientation_sigma_deg": tc.hand_guiding_orientation_deg,
        },
        "twin_truth": {
            "T_B_T": pose_list(twin.cell.world().T_B_T),
            "C_Pos_0_true": pose_list(C_Pos_0_true),
            "g_Pos_0_install_error": twin.cell.install_error().as_dict(),
        },
    }
    return write_dataset(dest, "teaching", manifest, {"template.png": frame.image})


# -- nine-point ---------------------------------------------------------------------------------


async def collect_nine_point(
    twin: TwinCell, config: CellConfig, cal: CalibrationSet, dest: Path, *, progress: Progress = _quiet
) -> Dataset:
    """Nine images over the window corner from the taught pose shifted in the wall plane, then the scale board."""
    npc = config.calibration.procedure.nine_point
    motion = motion_settings(config)
    taught = cal.taught()
    offsets = nine_point_offsets(npc.step_mm)
    targets = nine_point_targets(taught.C_Pos_0, taught.T0, offsets)
    samples = await collect_images(twin.robot, twin.camera, targets, motion, prefix="offset", progress=progress)
    if samples.skipped:
        raise CalibrationRefused("pixel_map", "unreachable", "; ".join(samples.skipped))
    await move_and_report(twin.robot, taught.C_Pos_0, motion)
    twin.stick_board(npc.scale_board, npc.scale_board_on_wall_mm)
    try:
        frame = await twin.camera.grab(timeout_s=motion.grab_timeout_s)
    finally:
        twin.remove_targets()
    manifest = {
        "source": twin.describe(),
        "views": [
            {"name": nm, "image": f"{nm}.png", "T_B_H": pose_list(h), "offset_target_mm": o.tolist()}
            for nm, h, o in zip(samples.names, samples.T_B_H, offsets)
        ],
        "C_Pos_0": pose_list(taught.C_Pos_0),
        "T0": pose_list(taught.T0),
        "scale_image": "scale.png",
        "scale_board": {**board_spec(npc.scale_board).as_dict(), "on_wall_mm": list(npc.scale_board_on_wall_mm)},
    }
    images = {f"{nm}.png": img for nm, img in zip(samples.names, samples.images)}
    images["scale.png"] = frame.image
    return write_dataset(dest, "nine_point", manifest, images)


# -- recording ----------------------------------------------------------------------------------


def validity_days(config: CellConfig, part: str) -> float:
    """How long a new part stays valid: the configuration's ``calibration.max_age_days``."""
    if part not in ("camera", "hand_eye", "laser", "pixel_map", "teaching"):
        raise KeyError(f"unknown calibration part {part!r}")
    return float(config.calibration.max_age_days)


def record(store: CalibrationStore, outcome: Outcome, ds: Dataset | None, config: CellConfig, when: datetime, note: str = "") -> CalibrationSet:
    """Store a successful calibration as a new version of the set."""
    part = make_part(
        outcome.part,
        values=outcome.values,
        method=outcome.method,
        when=when,
        valid_days=validity_days(config, outcome.part),
        quality=outcome.quality,
        warnings=outcome.warnings,
        inputs=outcome.inputs,
        dataset=None if ds is None else ds.ref({"kind": ds.kind}),
        software=software(),
    )
    return store.commit(outcome.part, part, note=note or f"{outcome.part} calibrated", now=when)


def record_failure(
    store: CalibrationStore, part: str, err: CalibrationRefused, ds: Dataset | None, config: CellConfig, when: datetime, method: str
) -> CalibrationSet:
    """Store a failed calibration: the part becomes 'failed' and production is refused until it is redone."""
    rec = make_part(
        part,
        values=None,
        method=method,
        when=when,
        valid_days=validity_days(config, part),
        quality={"reason": err.reason},
        dataset=None if ds is None else ds.ref({"kind": ds.kind}),
        software=software(),
        failure=err.detail,
    )
    return store.commit(part, rec, note=f"{part} calibration failed: {err.reason}", now=when)


def dataset_dir(store_root: str | Path, kind: str, when: datetime) -> Path:
    """Where a dataset collected now goes by default."""
    return default_dataset_dir(store_root, kind, when)
