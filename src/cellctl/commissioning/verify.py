"""``cellctl calibrate verify``: how far the camera and the laser have moved since they were calibrated.

A knock on the fixture moves the camera or the laser head, and every cycle after it is off by as
much. A full recalibration takes the better part of an hour; this check takes minutes. It goes
back to a few of the poses the stored calibrations were collected at (board views of the
hand-eye dataset, laser poses at a few arm stands of the laser dataset), collects again, and
computes hand-eye and laser twice with the same estimators: from the new data, and from the
same subset of the stored dataset. The difference of the two is the drift. At the same
commanded poses the robot makes the same absolute-accuracy errors, so they cancel; what remains
is the robot's repeatability and the sensors' noise (the report gives the drift figures and the
limits they are held to, ``calibration.procedure.verify``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cellctl.calibration.board import BoardSpec, find_board
from cellctl.calibration.calibration_set import CalibrationSet
from cellctl.calibration.compute import Outcome
from cellctl.calibration.dataset import Dataset, DatasetError, pose_array, pose_list, read_dataset
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.hand_eye import HandEyeLimits, board_pose, solve_hand_eye
from cellctl.calibration.laser import LaserLimits, calibrate_laser
from cellctl.commissioning.context import JobContext
from cellctl.commissioning.plans import MotionPlan, board_place, make_plan, spread_subset
from cellctl.commissioning.procedures import confirm_start, current_pose, grab, move_to, PoseRefused, place_board, remove_board
from cellctl.commissioning.procedures import car_body_in_place
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import Pose
from cellctl.geometry.rotation import angle_between_vectors, rotation_angle_between
from cellctl.ports import LaserStatus

# A subset solve needs at least this many views (the full calibration's gate is higher).
MIN_VERIFY_VIEWS = 4


def _reference(cal: CalibrationSet, part: str, kind: str) -> Dataset:
    p = cal.part(part)
    if p is None or p.status != "ok":
        raise CalibrationRefused("verify", "missing_input", f"{part} must be calibrated before it can be verified")
    if p.dataset is None:
        raise CalibrationRefused(
            "verify", "missing_input",
            f"the stored {part} calibration names no dataset (it was computed without one); recalibrate it once with "
            f"`cellctl calibrate {part.replace('_', '-')}` so that later checks can go back to its poses",
        )  # fmt: skip
    try:
        ds = read_dataset(p.dataset.path, kind)
    except DatasetError as err:
        raise CalibrationRefused("verify", "missing_input", f"the {part} calibration's dataset cannot be read: {err}") from None
    if ds.ref().manifest_sha256 != p.dataset.manifest_sha256:
        raise CalibrationRefused("verify", "bad_dataset", f"{ds.root}: the dataset changed since {part} was computed from it")
    return ds


def _laser_subset(rows: list[dict[str, Any]], stands: int, per_stand: int) -> list[int]:
    """Indices of ``per_stand`` readings at each of ``stands`` arm stands spread over the dataset's."""
    groups = sorted({int(r.get("group", 0)) for r in rows})
    chosen = [groups[i] for i in spread_subset(len(groups), stands)] if stands else []
    out: list[int] = []
    for g in chosen:
        members = [k for k, r in enumerate(rows) if int(r.get("group", 0)) == g and r.get("status") == "ok"]
        out.extend(members[i] for i in spread_subset(len(members), per_stand))
    return out


def plan_verify(config: CellConfig, cal: CalibrationSet | None, *, start: Pose | None = None) -> MotionPlan:
    """Board views, then laser poses, each a subset of the poses of the stored calibration's dataset."""
    if cal is None:
        raise CalibrationRefused("verify", "missing_input", "there is no calibration set to verify; commission the cell first")
    vc = config.calibration.procedure.verify
    board_ds = _reference(cal, "hand_eye", "board_views")
    views = board_ds.manifest["views"]
    view_idx = spread_subset(len(views), vc.views)
    poses = [pose_array(views[i].get("T_B_H_target", views[i]["T_B_H"]), f"{views[i]['name']}.T_B_H_target") for i in view_idx]
    labels = [f"view {views[i]['name']}" for i in view_idx]
    laser_idx: list[int] = []
    laser_ref: str | None = None
    if vc.laser_stands:
        laser_ds = _reference(cal, "laser", "laser_plane")
        rows = laser_ds.manifest["readings"]
        laser_idx = _laser_subset(rows, vc.laser_stands, vc.laser_poses_per_stand)
        poses += [pose_array(rows[i].get("T_B_H_target", rows[i]["T_B_H"]), f"reading {i}") for i in laser_idx]
        labels += [f"laser reading {i} (stand {rows[i].get('group', 0)})" for i in laser_idx]
        laser_ref = str(laser_ds.root)
    board = board_ds.manifest["board"]
    spec = BoardSpec(tuple(board["inner_corners"]), float(board["square_mm"]))  # type: ignore[arg-type]
    board_cfg = config.calibration.procedure.camera.board
    details = {
        "hand_eye_dataset": str(board_ds.root),
        "view_names": [views[i]["name"] for i in view_idx],
        "laser_dataset": laser_ref,
        "laser_readings": laser_idx,
        "board": board_place(config, board_cfg.model_copy(update={"square_mm": spec.square_mm}), board.get("on_wall_mm", [0.0, 0.0])),
        "views": len(view_idx),
    }
    return make_plan(config, "verify", poses, labels, [], start, details)


async def collect_verify(ctx: JobContext) -> Dataset:
    """Revisit the planned subset with the board on the wall, then the laser poses; save the dataset."""
    plan = plan_verify(ctx.config, ctx.calibration, start=await current_pose(ctx))
    n_views = plan.details["views"]
    await car_body_in_place(ctx, "A car body stands clamped in the cell at its nominal place (as when the cell was calibrated); confirm.")
    square = await place_board(ctx, plan.details["board"], "checkerboard")
    b = plan.details["board"]["board"]
    draft = ctx.begin(
        "verify",
        board={"inner_corners": b["inner_corners"], "square_mm": square, "border_mm": b["border_mm"]},
        reference={"hand_eye_dataset": plan.details["hand_eye_dataset"], "laser_dataset": plan.details["laser_dataset"]},
        views=[],
        readings=[],
        skipped=[],
        plan=plan.summary(),
    )
    await confirm_start(ctx, plan, "the calibration check")
    n = len(plan.poses)
    for k, (X, label) in enumerate(zip(plan.poses, plan.labels)):
        if k == n_views:
            await remove_board(ctx, "checkerboard")
        try:
            reported = await move_to(ctx, X)
        except PoseRefused as err:
            draft.manifest["skipped"].append(f"{label}: the robot refused it ({err})")
            continue
        if k < n_views:
            name = plan.details["view_names"][k]
            frame = await grab(ctx)
            draft.images[f"{name}.png"] = frame.image
            draft.manifest["views"].append({"name": name, "image": f"{name}.png", "T_B_H": pose_list(reported), "T_B_H_target": pose_list(X)})
        else:
            reading = await ctx.devices.laser.read(timeout_s=ctx.motion.read_timeout_s)
            ref_index = plan.details["laser_readings"][k - n_views]
            draft.manifest["readings"].append({
                "reference_index": ref_index, "T_B_H": pose_list(reported), "T_B_H_target": pose_list(X),
                "status": reading.status.value, "distance_mm": reading.distance_mm if reading.status is LaserStatus.OK else None,
            })  # fmt: skip
        ctx.progress(k + 1, n, label)
    if n <= n_views:
        await remove_board(ctx, "checkerboard")
    return ctx.finish()


def _views_hand_eye(ds: Dataset, names: list[str], spec: BoardSpec, K: np.ndarray, D: np.ndarray, refine: str) -> dict[str, tuple[Pose, Pose]]:
    by_name = {v["name"]: v for v in ds.manifest["views"]}
    out = {}
    for name in names:
        v = by_name.get(name)
        if v is None:
            continue
        det = find_board(ds.image(v["image"]), spec, refine=refine)  # type: ignore[arg-type]
        if not det.found:
            continue
        T_C_P, _ = board_pose(spec.object_points(), det.corners_px, K, D)
        out[name] = (pose_array(v["T_B_H"], f"{name}.T_B_H"), T_C_P)
    return out


def hand_eye_drift(new: Dataset, reference: Dataset, cal: CalibrationSet, refine: str) -> dict[str, Any]:
    """Hand-eye from the new views and from the same views of the reference dataset, and their difference."""
    K, D = cal.camera_matrix(), cal.dist_coeffs()
    b_new, b_ref = new.manifest["board"], reference.manifest["board"]
    spec_new = BoardSpec(tuple(b_new["inner_corners"]), float(b_new["square_mm"]))  # type: ignore[arg-type]
    spec_ref = BoardSpec(tuple(b_ref["inner_corners"]), float(b_ref["square_mm"]))  # type: ignore[arg-type]
    names = [v["name"] for v in new.manifest["views"]]
    got_new = _views_hand_eye(new, names, spec_new, K, D, refine)
    got_ref = _views_hand_eye(reference, names, spec_ref, K, D, refine)
    common = [n for n in names if n in got_new and n in got_ref]
    if len(common) < MIN_VERIFY_VIEWS:
        raise CalibrationRefused(
            "verify", "board_not_found",
            f"the board was found in only {len(common)} of the {len(names)} views in both the new and the stored data; "
            f"at least {MIN_VERIFY_VIEWS} are needed: check the board's place and the lighting",
        )  # fmt: skip
    limits = HandEyeLimits(min_views=MIN_VERIFY_VIEWS, recommended_views=MIN_VERIFY_VIEWS)
    X_new = solve_hand_eye([got_new[n][0] for n in common], [got_new[n][1] for n in common], methods=("tsai",), limits=limits).T_H_C
    X_ref = solve_hand_eye([got_ref[n][0] for n in common], [got_ref[n][1] for n in common], methods=("tsai",), limits=limits).T_H_C
    dt = X_new[:3, 3] - X_ref[:3, 3]
    return {
        "views": len(common),
        "translation_mm": float(np.linalg.norm(dt)),
        "translation_components_mm": dt.tolist(),
        "rotation_deg": float(np.degrees(rotation_angle_between(X_new[:3, :3], X_ref[:3, :3]))),
        "T_H_C_now": X_new.tolist(),
        "T_H_C_then": X_ref.tolist(),
    }


def _laser_fit(rows: list[dict[str, Any]], ds_ref: Dataset, config: CellConfig) -> Any:
    lc = config.calibration.procedure.laser
    ok = [r for r in rows if r["status"] == "ok" and r["distance_mm"] is not None]
    H = np.array([pose_array(r["T_B_H"], "reading.T_B_H") for r in ok]).reshape(-1, 4, 4)
    d = np.array([float(r["distance_mm"]) for r in ok])
    g = np.array([int(r.get("group", 0)) for r in ok], dtype=int)
    lo, hi = ds_ref.manifest["sensor_range_mm"]
    limits = LaserLimits(min_poses=12, min_direction_spread_deg=lc.min_direction_spread_deg, max_rms_mm=lc.max_rms_mm,
                         max_r_sigma_mm=10.0, max_l_sigma_deg=5.0)  # fmt: skip
    return calibrate_laser(
        H, d, ds_ref.manifest["r_nominal"], ds_ref.manifest["l_nominal"], groups=g,
        linearity_terms=lc.linearity_terms, distance_range_mm=(float(lo), float(hi)), limits=limits,
    )  # fmt: skip


def laser_drift(new: Dataset, reference: Dataset, config: CellConfig) -> dict[str, Any]:
    """r and l from the new readings and from the same readings of the reference dataset, and their difference."""
    ref_rows = reference.manifest["readings"]
    pairs = [(r, ref_rows[int(r["reference_index"])]) for r in new.manifest["readings"]]
    pairs = [(a, b) for a, b in pairs if a["status"] == "ok" and b["status"] == "ok"]
    if len(pairs) < 12:
        raise CalibrationRefused("verify", "laser", f"only {len(pairs)} laser readings with a value in both the new and the stored data; at least 12 are needed")
    new_rows = [{**a, "group": int(b.get("group", 0))} for a, b in pairs]
    now = _laser_fit(new_rows, reference, config)
    then = _laser_fit([b for _, b in pairs], reference, config)
    return {
        "readings": len(pairs),
        "r_mm": float(np.linalg.norm(now.r - then.r)),
        "r_components_mm": (now.r - then.r).tolist(),
        "l_deg": float(np.degrees(angle_between_vectors(now.l, then.l))),
        "r_sigma_mm": float(np.hypot(np.linalg.norm(now.r_sigma_mm), np.linalg.norm(then.r_sigma_mm))),
        "l_sigma_deg": float(np.hypot(np.linalg.norm(now.l_sigma_deg), np.linalg.norm(then.l_sigma_deg))),
    }


def compute_verify(ds: Dataset, cal: CalibrationSet | None, config: CellConfig) -> Outcome:
    """The drift of hand-eye and laser, and whether it is within ``calibration.procedure.verify``'s limits."""
    if cal is None:
        raise CalibrationRefused("verify", "missing_input", "there is no calibration set to verify")
    vc = config.calibration.procedure.verify
    ref = ds.manifest["reference"]
    hand_eye_ref = read_dataset(ref["hand_eye_dataset"], "board_views")
    he = hand_eye_drift(ds, hand_eye_ref, cal, config.calibration.procedure.camera.refine)
    beyond = []
    if he["translation_mm"] > vc.max_hand_eye_mm or he["rotation_deg"] > vc.max_hand_eye_deg:
        beyond.append(f"hand-eye moved {he['translation_mm']:.3f} mm / {he['rotation_deg']:.4f} deg "
                      f"(limits {vc.max_hand_eye_mm:g} mm, {vc.max_hand_eye_deg:g} deg): `cellctl calibrate hand-eye`")  # fmt: skip
    quality: dict[str, Any] = {"hand_eye": he, "limits": vc.model_dump()}
    summary = [f"hand-eye: {he['translation_mm']:.3f} mm, {he['rotation_deg']:.4f} deg from the stored calibration's data "
               f"({he['views']} views; limits {vc.max_hand_eye_mm:g} mm, {vc.max_hand_eye_deg:g} deg)"]  # fmt: skip
    if ref.get("laser_dataset") and ds.manifest["readings"]:
        la = laser_drift(ds, read_dataset(ref["laser_dataset"], "laser_plane"), config)
        quality["laser"] = la
        summary.append(f"laser: r {la['r_mm']:.3f} mm, l {la['l_deg']:.4f} deg ({la['readings']} readings; limits "
                       f"{vc.max_laser_r_mm:g} mm, {vc.max_laser_l_deg:g} deg)")  # fmt: skip
        if la["r_mm"] > vc.max_laser_r_mm or la["l_deg"] > vc.max_laser_l_deg:
            beyond.append(f"laser moved r {la['r_mm']:.3f} mm / l {la['l_deg']:.4f} deg (limits {vc.max_laser_r_mm:g} mm, "
                          f"{vc.max_laser_l_deg:g} deg): `cellctl calibrate laser`")  # fmt: skip
    quality["passed"] = not beyond
    quality["beyond_limits"] = beyond
    summary.append("within limits: the stored calibration still holds" if not beyond else "DRIFT: " + "; ".join(beyond))
    truth = ds.manifest.get("twin_truth")
    if truth:
        quality["twin_truth"] = truth
    return Outcome("verify", "revisit and recompute against the stored calibration's own data", {}, quality, beyond, {}, summary, None)
