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

import asyncio
import logging
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.calibration.board import BoardSpec, find_board
from cellctl.calibration.calibration_set import CalibrationSet
from cellctl.calibration.compute import Outcome
from cellctl.calibration.dataset import (
    Dataset,
    DatasetError,
    dataset_folder,
    pose_array,
    pose_list,
    read_dataset,
    stored_path,
)
from cellctl.calibration.dataset_retention import prune_check_datasets
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.hand_eye import board_pose
from cellctl.cell.cancel import to_the_end
from cellctl.commissioning.camera_grab import grab
from cellctl.commissioning.context import JobContext
from cellctl.commissioning.plans import MotionPlan, board_place, make_plan, spread_subset
from cellctl.commissioning.procedures import (
    board_hint,
    board_recipe,
    car_body_in_place,
    confirm_start,
    current_pose,
    move_or_skip,
    place_board,
    remove_board,
)
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import Pose, invert_pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix, matrix_to_axis_angle, skew
from cellctl.ports import LaserStatus

log = logging.getLogger(__name__)

# A subset solve needs at least this many views (the full calibration's gate is higher).
MIN_VERIFY_VIEWS = 4
GAUSS_NEWTON_STEPS = 3


def _reference(cal: CalibrationSet, part: str, kind: str, store_root: Path | None) -> Dataset:
    """The dataset the stored ``part`` was computed from, found in the store at ``store_root`` (:func:`dataset_folder`)."""
    p = cal.part(part)
    if p is None or p.status != "ok":
        raise CalibrationRefused("verify", "missing_input", f"{part} must be calibrated before it can be verified")
    if p.dataset is None:
        raise CalibrationRefused(
            "verify", "missing_input",
            f"the stored {part} calibration names no dataset (it was computed without one); recalibrate it once with "
            f"`cellctl calibrate {part.replace('_', '-')}` so that later checks can go back to its poses",
        )  # fmt: skip
    folder = dataset_folder(p.dataset.path, store_root)
    try:
        ds = read_dataset(folder, kind)
    except DatasetError as err:
        raise CalibrationRefused("verify", "missing_input", f"the {part} calibration's dataset cannot be read: {err}"
                                 + _where_looked(p.dataset.path, folder, store_root)) from None
    if ds.ref().manifest_sha256 != p.dataset.manifest_sha256:
        raise CalibrationRefused("verify", "bad_dataset", f"{ds.root}: the dataset changed since {part} was computed from it")
    return ds


def _where_looked(stored: str, folder: Path, store_root: Path | None) -> str:
    """What a missing dataset's message adds: where it was looked for, and how to get it back ("" when it is there)."""
    if folder.is_dir() or store_root is None:
        return ""
    moved = Path(store_root) / "datasets" / Path(stored).name
    where = str(folder) if folder == moved else f"{folder} nor {moved}"
    return (f" (the set names {stored}: neither {where} exists). A store moved to another folder takes its datasets "
            "along: copy the whole calibration.directory, its datasets folder included; a dataset lost for good is "
            "made again by that part's calibration")


def _laser_subset(rows: list[dict[str, Any]], stands: int, per_stand: int) -> list[int]:
    """Indices of ``per_stand`` readings at each of ``stands`` arm stands spread over the dataset's."""
    groups = sorted({int(r.get("group", 0)) for r in rows})
    chosen = [groups[i] for i in spread_subset(len(groups), stands)] if stands else []
    out: list[int] = []
    for g in chosen:
        members = [k for k, r in enumerate(rows) if int(r.get("group", 0)) == g and r.get("status") == "ok"]
        out.extend(members[i] for i in spread_subset(len(members), per_stand))
    return out


# The stored board datasets a check goes back to: the hand-eye's views, and the camera's (the
# same camera on the same flange, a few minutes earlier), each with the board where it was then.
BOARD_REFERENCES = ("hand_eye", "camera")


def plan_verify(
    config: CellConfig, cal: CalibrationSet | None, *, start: Pose | None = None, store_root: Path | None = None
) -> MotionPlan:
    """Board views, then laser poses, each a subset of the poses of the stored calibrations' datasets (found in the
    calibration store at ``store_root``; the plan names them relative to it, as the check's manifest does)."""
    if cal is None:
        raise CalibrationRefused("verify", "missing_input", "there is no calibration set to verify; commission the cell first")
    vc = config.calibration.procedure.verify
    poses: list[Pose] = []
    labels: list[str] = []
    views: list[dict[str, str]] = []
    references: dict[str, str] = {}
    board: dict[str, Any] | None = None
    for part in BOARD_REFERENCES:
        p = cal.part(part)
        if part != "hand_eye" and (p is None or p.dataset is None
                                   or stored_path(dataset_folder(p.dataset.path, store_root), store_root) in references.values()):
            continue  # the hand-eye's views are needed; the camera's add precision when they are there
        ds = _reference(cal, part, "board_views", store_root)
        references[part] = stored_path(ds.root, store_root)
        board = board or ds.manifest["board"]
        rows = ds.manifest["views"]
        for i in spread_subset(len(rows), vc.views):
            poses.append(pose_array(rows[i].get("T_B_H_target", rows[i]["T_B_H"]), f"{rows[i]['name']}.T_B_H_target"))
            labels.append(f"{part} view {rows[i]['name']}")
            views.append({"name": f"{part}-{rows[i]['name']}", "reference": part, "reference_name": rows[i]["name"]})
    laser_idx: list[int] = []
    laser_ref: str | None = None
    if vc.laser_stands:
        laser_ds = _reference(cal, "laser", "laser_plane", store_root)
        rows = laser_ds.manifest["readings"]
        laser_idx = _laser_subset(rows, vc.laser_stands, vc.laser_poses_per_stand)
        poses += [pose_array(rows[i].get("T_B_H_target", rows[i]["T_B_H"]), f"reading {i}") for i in laser_idx]
        labels += [f"laser reading {i} (stand {rows[i].get('group', 0)})" for i in laser_idx]
        laser_ref = stored_path(laser_ds.root, store_root)
    assert board is not None
    board_cfg = config.calibration.procedure.camera.board
    details = {
        "board_datasets": references,
        "views_planned": views,
        "laser_dataset": laser_ref,
        "laser_readings": laser_idx,
        "board": board_place(config, board_cfg.model_copy(update={"square_mm": float(board["square_mm"])}), board.get("on_wall_mm", [0.0, 0.0])),
        "views": len(views),
    }
    return make_plan(config, "verify", poses, labels, [], start, details)


SAME_BOARD = 0.0005  # a measured square size this near the calibration's (0.05 %) is the same board


async def collect_verify(ctx: JobContext) -> Dataset:
    """Revisit the planned subset with the board on the wall, then the laser poses; save the dataset."""
    plan = await asyncio.to_thread(plan_verify, ctx.config, ctx.calibration, start=await current_pose(ctx),
                                   store_root=ctx.store_root)  # fmt: skip
    n_views = plan.details["views"]
    recipe = board_recipe(ctx.config)  # the board goes beside its opening, as when the cell was calibrated
    await car_body_in_place(ctx, "A car body stands clamped in the cell at its nominal place (as when the cell was calibrated); "
                            "confirm.", recipe=recipe)  # fmt: skip
    square = await place_board(ctx, plan.details["board"], "checkerboard", recipe)
    b = plan.details["board"]["board"]
    if abs(square / float(b["square_mm"]) - 1.0) > SAME_BOARD:  # a scale error reads as the camera having moved
        raise CalibrationRefused(
            "verify", "other_board",
            f"the check compares with the board the cell was calibrated with ({float(b['square_mm']):.3f} mm squares), "
            f"but {square:.3f} mm was given: confirm that board's size, or for another board calibrate again "
            "(cellctl calibrate camera, then hand-eye)",
        )  # fmt: skip
    draft = ctx.begin(
        "verify",
        board={"inner_corners": b["inner_corners"], "square_mm": square, "border_mm": b["border_mm"]},
        reference={"board_datasets": plan.details["board_datasets"], "laser_dataset": plan.details["laser_dataset"]},
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
        reported = await move_or_skip(ctx, draft, X, label, None, refused="the robot refused it")
        if reported is None:
            continue
        if k < n_views:
            view = plan.details["views_planned"][k]
            frame = await grab(ctx, "verify")
            draft.images[f"{view['name']}.png"] = frame.image
            draft.manifest["views"].append({**view, "image": f"{view['name']}.png", "T_B_H": pose_list(reported), "T_B_H_target": pose_list(X)})
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
    return await keep_fewer_checks(ctx, await ctx.finish())


async def keep_fewer_checks(ctx: JobContext, ds: Dataset) -> Dataset:
    """Remove the oldest check datasets beyond ``calibration.procedure.verify.keep_datasets`` from the store's
    ``datasets`` folder (never ``ds``, never one a set version names); what was done goes to ``ds.notes``."""
    if ctx.store_root is None or ds.root.parent != ctx.store_root / "datasets":  # not the store's folder: leave it
        return ds
    keep = ctx.config.calibration.procedure.verify.keep_datasets
    try:
        report, cancelled = await to_the_end(asyncio.to_thread(prune_check_datasets, ctx.store_root, keep, just_written=ds.root))
    except OSError as err:  # the check itself is complete: it is computed and recorded all the same
        log.warning("calibration datasets: the older check datasets could not be pruned: %s", err)
        return ds
    if cancelled:
        raise asyncio.CancelledError
    return replace(ds, notes={**ds.notes, "datasets": report.as_dict()})


def _board_poses(ds: Dataset, names: list[str], spec: BoardSpec, K: np.ndarray, D: np.ndarray, refine: str) -> dict[str, tuple[Pose, Pose]]:
    """Per view name: (reported flange pose T_B_H, board pose T_C_P by PnP), for the views where the board was found."""
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


def _twist(T: np.ndarray) -> np.ndarray:
    """A small rigid motion as (translation mm, rotation vector rad)."""
    return np.concatenate([T[:3, 3], matrix_to_axis_angle(T[:3, :3])])


def _adjoint_inv(C: np.ndarray) -> np.ndarray:
    """The 6x6 map of a twist (v, w) given in the base frame to C^-1 [twist] C (v, w in C's frame)."""
    R, t = C[:3, :3], C[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R.T
    A[:3, 3:] = -R.T @ skew(t)
    A[3:, 3:] = R.T
    return A


def camera_drift(
    then: list[Pose], now: list[Pose], cameras_B: list[Pose], groups: list[int] | None = None, *, lever_mm: float = 400.0
) -> tuple[np.ndarray, np.ndarray, float]:
    """The camera's move on the flange, from board poses seen at the same flange poses before and now.

    At view i the camera sees the board at ``then[i]`` before and ``now[i]`` now (T_C_P). If the
    camera moved on the flange by Delta (X_now = X_then @ Delta) and the board on the wall by M
    (in the base frame), then ``now[i] @ inv(then[i]) = inv(Delta) @ inv(C_i) @ M @ C_i`` with C_i
    the camera pose in the base frame; to first order the twist of the left side is
    ``-delta + Ad(inv(C_i)) m``. Delta and one M per group (views whose "before" had the board
    in one place: one per stored dataset) are found together by Gauss-Newton over the views
    (rotations weighted by ``lever_mm``). Returns Delta as a 4x4, its twist's 6x6 covariance
    (mm, rad) from the residuals, and the residual RMS (mm).
    """
    g = [0] * len(then) if groups is None else list(groups)
    if not (len(then) == len(now) == len(cameras_B) == len(g)) or len(then) < MIN_VERIFY_VIEWS:
        raise ValueError(f"need at least {MIN_VERIFY_VIEWS} views with the board seen before and now")
    labels = sorted(set(g))
    col = {label: k for k, label in enumerate(labels)}
    W = np.diag([1.0, 1.0, 1.0, lever_mm, lever_mm, lever_mm])
    rows = []
    for C, label in zip(cameras_B, g):
        block = np.zeros((6, 6 + 6 * len(labels)))
        block[:, :6] = -np.eye(6)
        block[:, 6 + 6 * col[label]: 12 + 6 * col[label]] = _adjoint_inv(C)
        rows.append(W @ block)
    J = np.vstack(rows)
    delta = np.eye(4)
    moves = [np.eye(4) for _ in labels]
    for _ in range(GAUSS_NEWTON_STEPS):  # relinearised about the estimate: a board re-stuck mm and tenths of a degree off
        y = np.concatenate([W @ _twist(delta @ A @ invert_pose(B) @ invert_pose(invert_pose(C) @ moves[col[label]] @ C))
                            for A, B, C, label in zip(now, then, cameras_B, g)])  # fmt: skip
        x, *_ = np.linalg.lstsq(J, y, rcond=None)
        delta = delta @ make_pose(axis_angle_to_matrix(x[3:6]), x[:3])
        for k in range(len(labels)):
            m = x[6 + 6 * k: 12 + 6 * k]
            moves[k] = make_pose(axis_angle_to_matrix(m[3:6]), m[:3]) @ moves[k]
    r = y - J @ x
    dof = max(len(y) - J.shape[1], 1)
    sigma2 = float(r @ r) / dof
    cov = sigma2 * np.linalg.pinv(J.T @ J)[:6, :6]
    return delta, cov, float(np.sqrt(sigma2))


def hand_eye_drift(new: Dataset, cal: CalibrationSet, refine: str, store_root: Path | None = None) -> dict[str, Any]:
    """How far the camera moved on the flange, from the new views and the same views of the stored datasets (the
    check's references, found in the store at ``store_root``: :func:`check_store`)."""
    K, D = cal.camera_matrix(), cal.dist_coeffs()
    X = cal.T_H_C()
    b_new = new.manifest["board"]
    spec_new = BoardSpec(tuple(b_new["inner_corners"]), float(b_new["square_mm"]))  # type: ignore[arg-type]
    views = new.manifest["views"]
    got_new = _board_poses(new, [v["name"] for v in views], spec_new, K, D, refine)
    then, now, cameras, groups = [], [], [], []
    for k, (part, path) in enumerate(new.manifest["reference"]["board_datasets"].items()):
        ref = read_dataset(dataset_folder(path, store_root), "board_views")
        b_ref = ref.manifest["board"]
        spec_ref = BoardSpec(tuple(b_ref["inner_corners"]), float(b_ref["square_mm"]))  # type: ignore[arg-type]
        mine = [v for v in views if v["reference"] == part]
        got_ref = _board_poses(ref, [v["reference_name"] for v in mine], spec_ref, K, D, refine)
        for v in mine:
            if v["name"] in got_new and v["reference_name"] in got_ref:
                H_ref, C_ref = got_ref[v["reference_name"]]
                then.append(C_ref)
                now.append(got_new[v["name"]][1])
                cameras.append(H_ref @ X)
                groups.append(k)
    if len(then) < MIN_VERIFY_VIEWS:
        raise CalibrationRefused(
            "verify", "board_not_found",
            f"the board was found in only {len(then)} of the {len(views)} views in both the new and the stored data; "
            f"at least {MIN_VERIFY_VIEWS} are needed: check the board's place and the lighting",
        )  # fmt: skip
    delta, cov, rms = camera_drift(then, now, cameras, groups)
    dt = X[:3, :3] @ delta[:3, 3]  # in the flange frame
    return {
        "views": len(then),
        "translation_mm": float(np.linalg.norm(dt)),
        "translation_components_mm": dt.tolist(),
        "rotation_deg": float(np.degrees(np.linalg.norm(matrix_to_axis_angle(delta[:3, :3])))),
        "translation_sigma_mm": float(np.sqrt(np.trace(cov[:3, :3]))),
        "rotation_sigma_deg": float(np.degrees(np.sqrt(np.trace(cov[3:, 3:])))),
        "residual_rms_mm": rms,
        "T_H_C_now": (X @ delta).tolist(),
    }


def _predicted(H: np.ndarray, r: np.ndarray, l: np.ndarray, n: np.ndarray, D: float) -> np.ndarray:  # noqa: E741
    """The distances the laser reads at flange poses H off the wall n . p = D (eq. 1 solved for d)."""
    o = np.einsum("nij,j->ni", H[:, :3, :3], r) + H[:, :3, 3]
    u = np.einsum("nij,j->ni", H[:, :3, :3], l)
    return (D - o @ n) / (u @ n)


def _normal_basis(v: np.ndarray) -> np.ndarray:
    """Two unit vectors (3, 2) normal to v."""
    return np.linalg.svd(np.eye(3) - np.outer(v, v))[0][:, :2]


def laser_ray_drift(
    T_B_H: np.ndarray, d_then: np.ndarray, d_now: np.ndarray, r: np.ndarray, l: np.ndarray  # noqa: E741
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """How far the laser's r and l moved, from distances read at the same flange poses before and now.

    Each reading's point p = H (r + d l) lies on the wall n . p = D (eq. 1). A move of the head
    (dr, dl) and of the wall (dn, dD) changes each reading; the arm's position error at a pose is
    the same before and now, so only the *change* of the readings is fitted: by Gauss-Newton, the
    change the model predicts between the stored ray and the moved one (with the wall moved too)
    against ``d_now - d_then``. Returns dr (mm), dl (the change of the unit vector l), their 6x6
    covariance, and the residual RMS (mm).
    """
    H = np.asarray(T_B_H, dtype=float)
    d0, d1 = np.asarray(d_then, dtype=float), np.asarray(d_now, dtype=float)
    P = np.einsum("nij,nj->ni", H[:, :3, :3], r[None, :] + d0[:, None] * l[None, :]) + H[:, :3, 3]
    c = P.mean(axis=0)
    n = np.linalg.svd(P - c)[2][2]
    if float(np.mean(np.einsum("nij,j->ni", H[:, :3, :3], l) @ n)) < 0:
        n = -n
    D = float(n @ c)
    base = _predicted(H, r, l, n, D)
    rk, lk, nk, Dk = r.copy(), l.copy(), n.copy(), D
    for _ in range(GAUSS_NEWTON_STEPS + 1):
        pred = _predicted(H, rk, lk, nk, Dk)
        y = (d1 - d0) - (pred - base)
        bl, bn = _normal_basis(lk), _normal_basis(nk)
        Pk = np.einsum("nij,nj->ni", H[:, :3, :3], rk[None, :] + pred[:, None] * lk[None, :]) + H[:, :3, 3]
        nR = np.einsum("j,nji->ni", nk, H[:, :3, :3])  # n . R_i as a row per reading
        inc = nR @ lk
        J = np.hstack([nR, (pred[:, None] * nR) @ bl, Pk @ bn, -np.ones((len(d0), 1))]) / -inc[:, None]
        x, *_ = np.linalg.lstsq(J, y, rcond=None)
        rk = rk + x[:3]
        lk = lk + bl @ x[3:5]
        lk = lk / np.linalg.norm(lk)
        nk = nk + bn @ x[5:7]
        nk = nk / np.linalg.norm(nk)
        Dk = Dk + float(x[7])
    res = (d1 - d0) - (_predicted(H, rk, lk, nk, Dk) - base)
    dof = max(len(y) - J.shape[1], 1)
    sigma2 = float(res @ res) / dof
    cov = sigma2 * np.linalg.pinv(J.T @ J)
    C = np.zeros((6, 6))
    C[:3, :3] = cov[:3, :3]
    C[3:, 3:] = bl @ cov[3:5, 3:5] @ bl.T
    return rk - r, lk - l, C, float(np.sqrt(sigma2))


def laser_drift(new: Dataset, reference: Dataset, cal: CalibrationSet) -> dict[str, Any]:
    """How far the laser moved, from the new readings and the same readings of the reference dataset."""
    ref_rows = reference.manifest["readings"]
    pairs = [(a, ref_rows[int(a["reference_index"])]) for a in new.manifest["readings"]]
    pairs = [(a, b) for a, b in pairs if a["status"] == "ok" and b["status"] == "ok" and a["distance_mm"] is not None and b["distance_mm"] is not None]
    if len(pairs) < 12:
        raise CalibrationRefused("verify", "laser", f"only {len(pairs)} laser readings with a value in both the new and the stored data; at least 12 are needed")
    r, l = cal.laser_ray()  # noqa: E741
    H = np.array([pose_array(b["T_B_H"], "reading.T_B_H") for _, b in pairs])
    dr, dl, cov, rms = laser_ray_drift(H, np.array([b["distance_mm"] for _, b in pairs]), np.array([a["distance_mm"] for a, _ in pairs]), r, l)
    return {
        "readings": len(pairs),
        "r_mm": float(np.linalg.norm(dr)),
        "r_components_mm": dr.tolist(),
        "l_deg": float(np.degrees(np.linalg.norm(dl))),
        "r_sigma_mm": float(np.sqrt(np.trace(cov[:3, :3]))),
        "l_sigma_deg": float(np.degrees(np.sqrt(np.trace(cov[3:, 3:])))),
        "residual_rms_mm": rms,
    }


def check_store(ds: Dataset, store_root: Path | None) -> Path | None:
    """The calibration store a check's reference datasets are found in: the one check dataset ``ds`` lies in
    (``<store>/datasets/<name>``: they moved with it), else ``store_root`` (the store the check is computed against)."""
    return ds.root.parent.parent if ds.root.parent.name == "datasets" else store_root


def compute_verify(ds: Dataset, cal: CalibrationSet | None, config: CellConfig, *, store_root: Path | None = None) -> Outcome:
    """The drift of hand-eye and laser, and whether it is within ``calibration.procedure.verify``'s limits; the check's
    reference datasets are found as :func:`check_store` says."""
    if cal is None:
        raise CalibrationRefused("verify", "missing_input", "there is no calibration set to verify")
    vc = config.calibration.procedure.verify
    ref = ds.manifest["reference"]
    root = check_store(ds, store_root)
    try:
        he = hand_eye_drift(ds, cal, config.calibration.procedure.camera.refine, root)
    except CalibrationRefused as err:
        raise board_hint(err, config) from None
    beyond = []
    if he["translation_mm"] > vc.max_hand_eye_mm or he["rotation_deg"] > vc.max_hand_eye_deg:
        beyond.append(f"hand-eye moved {he['translation_mm']:.3f} mm / {he['rotation_deg']:.4f} deg "
                      f"(limits {vc.max_hand_eye_mm:g} mm, {vc.max_hand_eye_deg:g} deg): `cellctl calibrate hand-eye`")  # fmt: skip
    quality: dict[str, Any] = {"hand_eye": he, "limits": vc.model_dump()}
    if ref.get("laser_dataset") and not ds.manifest["readings"]:  # planned, but the robot took none of its poses
        skipped = [s for s in ds.manifest.get("skipped", []) if str(s).startswith("laser reading")]
        raise CalibrationRefused(
            "verify", "laser_not_checked",
            f"the laser was not checked: all {len(skipped)} laser poses were skipped ({'; '.join(skipped[:3])}"
            f"{'; ...' if len(skipped) > 3 else ''}); the hand-eye moved {he['translation_mm']:.3f} mm / "
            f"{he['rotation_deg']:.4f} deg. Remove what made the robot refuse them (the reasons above) "
            "and run the check again",
        )  # fmt: skip
    if ref.get("laser_dataset"):
        la = laser_drift(ds, read_dataset(dataset_folder(ref["laser_dataset"], root), "laser_plane"), cal)
        quality["laser"] = la
        if la["r_mm"] > vc.max_laser_r_mm or la["l_deg"] > vc.max_laser_l_deg:
            beyond.append(f"laser moved r {la['r_mm']:.3f} mm / l {la['l_deg']:.4f} deg (limits {vc.max_laser_r_mm:g} mm, "
                          f"{vc.max_laser_l_deg:g} deg): `cellctl calibrate laser`")  # fmt: skip
    quality["passed"] = not beyond
    quality["beyond_limits"] = beyond
    truth = ds.manifest.get("twin_truth")
    if truth:
        quality["twin_truth"] = truth
    if "datasets" in ds.notes:  # the check datasets kept and pruned after this one was written, the folder's MiB
        quality["datasets"] = ds.notes["datasets"]
    return Outcome("verify", "revisit and recompute against the stored calibration's own data", {}, quality, beyond, {}, None)
