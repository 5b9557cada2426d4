"""From a saved dataset to a calibration part: the offline half of every calibration command.

Each ``compute_*`` reads only the dataset (and, where a part builds on others, the current
calibration set), so any calibration can be recomputed later from its folder and compared. The
result is an :class:`Outcome`: the values for the calibration set, the quality figures, warnings,
the ids of the parts used, and a few readable summary lines. Data that cannot give a trustworthy
result raises CalibrationRefused with the reason.

A dataset recorded in the simulated cell carries the simulator's truth under ``twin_truth``; it
is never used in a computation, only compared with the result afterwards (``quality.twin_truth``),
so a simulated run reports its true error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cellctl.align import AlignmentError, AlignmentResult, compute_alignment, readings_at_stops
from cellctl.calibration.board import BoardDetection, BoardSpec, find_board
from cellctl.calibration.calibration_set import CalibrationSet, parts_of, recipe_slot
from cellctl.calibration.camera import ViewCorners, calibrate_camera
from cellctl.calibration.dataset import Dataset, pose_array
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.hand_eye import board_pose, refuse_disagreement, solve_hand_eye
from cellctl.calibration.laser import calibrate_laser
from cellctl.calibration.pixel_map import accept_nine_point_map, nine_point_map, offsets_from_poses
from cellctl.calibration.summary import summary_lines
from cellctl.calibration.taught_shot import refuse_changed_shot, taught_profile, taught_shot
from cellctl.calibration.teach import workpiece_frame_from_corner
from cellctl.calibration.template_figures import corner_angle_deg, taught_feature
from cellctl.compensate import deviation_in_frame
from cellctl.config.feature import shot_feature
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import check_pose, invert_pose, make_pose, mean_pose, pose_error
from cellctl.geometry.rotation import angle_between_vectors, rotation_angle_between
from cellctl.vision.feature import detect_feature
from cellctl.vision.ninepoint import NinePointError
from cellctl.vision.scale import ScaleCalibrationError, checkerboard_scale


@dataclass
class Outcome:
    """One computed calibration part, ready for the calibration set."""

    part: str
    method: str
    values: dict[str, Any]
    quality: dict[str, Any]
    warnings: list[str] = field(default_factory=list)
    inputs: dict[str, str] = field(default_factory=dict)
    detail: Any = None
    recipe: str | None = None  # whose own part it is (teaching, pixel_map of a recipe but the first); None: the set's

    @property
    def summary(self) -> list[str]:
        """The outcome in a few readable lines (cellctl.calibration.summary)."""
        return summary_lines(self.part, self.values, self.quality)


def _board(ds: Dataset) -> BoardSpec:
    b = ds.manifest.get("board")
    if not isinstance(b, dict):
        raise CalibrationRefused("camera", "bad_dataset", f"{ds.root}: the manifest does not describe the board")
    return BoardSpec(tuple(b["inner_corners"]), float(b["square_mm"]))  # type: ignore[arg-type]


def _need(cal: CalibrationSet | None, part: str, name: str, recipe: str | None = None) -> str:
    """The id of a part this calibration builds on (``recipe``'s own, when it names one), refusing when it is not usable."""
    if cal is None:
        raise CalibrationRefused(part, "missing_input", f"{name} is not calibrated yet: there is no calibration set")
    p = cal.part(name, recipe)
    if p is None or p.status != "ok":
        state = "missing" if p is None else "failed"
        raise CalibrationRefused(part, "missing_input", f"{name} is {state} in the calibration set; calibrate it first")
    return p.id


def detect_views(ds: Dataset, refine: str = "subpix") -> list[tuple[str, BoardDetection]]:
    """The board in every view of a board_views dataset."""
    spec = _board(ds)
    return [(v["name"], find_board(ds.image(v["image"]), spec, refine=refine)) for v in ds.manifest["views"]]  # type: ignore[arg-type]


# -- camera -------------------------------------------------------------------------------------


def compute_camera(
    ds: Dataset, config: CellConfig, detections: list[tuple[str, BoardDetection]] | None = None
) -> Outcome:
    """Intrinsics (Zhang) from a board_views dataset."""
    cc = config.calibration.procedure.camera
    spec = _board(ds)
    dets = detections if detections is not None else detect_views(ds, cc.refine)
    views = [ViewCorners(name, d.corners_px, d.reason) for name, d in dets]
    size = tuple(int(x) for x in ds.manifest["image_size"])
    res = calibrate_camera(views, spec.object_points(), size, fix_k3=cc.fix_k3, limits=cc)  # type: ignore[arg-type]
    i = res.intrinsics
    sharp = [d.sharpness_px for _, d in dets if d.sharpness_px is not None]
    quality: dict[str, Any] = {
        "rms_px": res.rms_px,
        "per_view_rms_px": res.per_view_rms_px,
        "rejected_views": [{"view": n, "reason": r} for n, r in res.rejected],
        "views_used": len(res.per_view_rms_px),
        "views_total": len(views),
        "std": res.std,
        "coverage": res.coverage,
        "tilt_spread_deg": res.tilt_spread_deg, "max_tilt_deg": res.max_tilt_deg, "view_focal_sigma": res.view_focal_sigma,
        "fix_k3": cc.fix_k3,
        "board_sharpness_px": float(np.median(sharp)) if sharp else None,
        "detection_s": float(sum(d.seconds for _, d in dets)),
    }
    warnings = []
    if res.coverage < 0.3:
        warnings.append(f"the corners covered only {res.coverage:.0%} of the image; add views reaching its corners")
    if res.rejected:
        warnings.append(f"{len(res.rejected)} view(s) left out: " + "; ".join(f"{n}: {r}" for n, r in res.rejected[:3]))
    truth = ds.manifest.get("twin_truth", {}).get("intrinsics")
    if truth:
        quality["twin_truth"] = {
            "fx_error_pct": 100.0 * (i.fx / truth["fx"] - 1.0),
            "fy_error_pct": 100.0 * (i.fy / truth["fy"] - 1.0),
            "cx_error_px": i.cx - truth["cx"],
            "cy_error_px": i.cy - truth["cy"],
        }
    return Outcome(
        "camera",
        "zhang (cv2.calibrateCameraExtended), corners by findChessboardCornersSB" + f" + {cc.refine}",
        {"K": i.camera_matrix.tolist(), "dist": i.dist_coeffs.tolist(), "image_size": list(size)},
        quality,
        warnings,
        {},
        res,
    )


# -- hand-eye -----------------------------------------------------------------------------------


def compute_hand_eye(
    ds: Dataset,
    cal: CalibrationSet | None,
    config: CellConfig,
    detections: list[tuple[str, BoardDetection]] | None = None,
) -> Outcome:
    """T_H_C from a board_views dataset, the robot's reported poses and the calibrated camera."""
    hc = config.calibration.procedure.hand_eye
    camera_id = _need(cal, "hand_eye", "camera")
    assert cal is not None
    K, D = cal.camera_matrix(), cal.dist_coeffs()
    spec = _board(ds)
    obj = spec.object_points()
    dets = dict(detections if detections is not None else detect_views(ds, config.calibration.procedure.camera.refine))
    H, C, corners, names, pnp = [], [], [], [], []
    missing = []
    for v in ds.manifest["views"]:
        d = dets.get(v["name"])
        if d is None or not d.found:
            missing.append(v["name"])
            continue
        T_C_P, rms = board_pose(obj, d.corners_px, K, D)
        H.append(pose_array(v["T_B_H"], f"{v['name']}.T_B_H"))
        C.append(T_C_P)
        corners.append(d.corners_px)
        names.append(v["name"])
        pnp.append(rms)
    if not H:
        raise CalibrationRefused("hand_eye", "board_not_found", f"the board was not found in any of the {len(ds.manifest['views'])} views")
    rep = solve_hand_eye(H, C, chosen=hc.method, limits=hc, object_points=obj, corners_px=corners, K=K, dist=D, names=names)
    worst_mm, worst_deg = refuse_disagreement(rep, hc)  # among the methods that agree; an outlier is a warning
    X = rep.T_H_C
    warnings = list(rep.warnings)
    if missing:
        warnings.append(f"board not found in {len(missing)} view(s): {', '.join(missing[:5])}")
    per_method = {}
    for m, s in rep.solutions.items():
        per_method[m] = {
            "translation_mm": s.T_H_C[:3, 3].tolist(),
            "rotation_rows": s.T_H_C[:3, :3].tolist(),
            "residual_rotation_rms_deg": s.residual.rotation_rms_deg,
            "residual_translation_rms_mm": s.residual.translation_rms_mm,
            "board_spread_mm": s.residual.board_spread_mm,
            "board_spread_deg": s.residual.board_spread_deg,
            "chain_reprojection_rms_px": s.residual.reprojection_rms_px,
            "from_chosen_mm": rep.agreement_mm[m],
            "from_chosen_deg": rep.agreement_deg[m],
        }
    d = rep.diversity
    quality: dict[str, Any] = {
        "chosen": rep.chosen,
        "methods": per_method,
        "views_used": len(H),
        "views_without_board": missing,
        "pnp_rms_px": {n: r for n, r in zip(names, pnp)},
        "motion": {
            "pairs": d.n_pairs,
            "pairs_left_out": d.pairs_left_out,
            "max_pair_angle_deg": d.max_pair_angle_deg,
            "median_pair_angle_deg": d.median_pair_angle_deg,
            "axis_spread": d.axis_spread,
            "axis_spread_3d": d.axis_spread_3d,
        },
        "max_disagreement_mm": worst_mm,
        "max_disagreement_deg": worst_deg,
        "methods_left_out": rep.outliers,
    }
    truth = ds.manifest.get("twin_truth", {}).get("T_H_C")
    if truth is not None:
        Xt = np.asarray(truth, dtype=float)
        tq = {}
        for m, s in rep.solutions.items():
            tq[m] = {
                "translation_error_mm": float(np.linalg.norm(s.T_H_C[:3, 3] - Xt[:3, 3])),
                "rotation_error_deg": float(np.degrees(rotation_angle_between(s.T_H_C[:3, :3], Xt[:3, :3]))),
            }
        quality["twin_truth"] = tq
    return Outcome(
        "hand_eye",
        f"{rep.chosen} (" + ("own implementation of Tsai-Lenz" if rep.chosen == "tsai" else "cv2.calibrateHandEye") + ")",
        {"T_H_C": X.tolist()},
        quality,
        warnings,
        {"camera": camera_id},
        rep,
    )


# -- laser --------------------------------------------------------------------------------------


def _readings(rows: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """T_B_H, distance and group of every reading with a value; a field that is not a finite number refused, named."""
    H, d, g = [], [], []
    for k, r in enumerate(rows):
        try:
            if r["status"] == "ok" and r["distance_mm"] is not None:
                H.append(check_pose(pose_array(r["T_B_H"], "T_B_H"), "T_B_H"))
                d.append(float(r["distance_mm"]))
                g.append(int(r.get("group", 0)))
                if not np.isfinite(d[-1]):
                    raise ValueError(f"distance_mm is {r['distance_mm']!r}")
        except (TypeError, ValueError) as err:
            raise CalibrationRefused(
                "laser", "bad_dataset", f"readings[{k}]: {err}: correct that reading in the dataset's manifest (a finite "
                "distance_mm, a rigid 4x4 T_B_H) or record the dataset again") from None
    return np.array(H).reshape(-1, 4, 4), np.array(d, dtype=float), np.array(g, dtype=int)


def compute_laser(ds: Dataset, config: CellConfig) -> Outcome:
    """r and l from a laser_plane dataset."""
    lc = config.calibration.procedure.laser
    rows = ds.manifest["readings"]
    H, d, g = _readings(rows)
    dropped = len(rows) - len(d)
    lo, hi = ds.manifest["sensor_range_mm"]
    res = calibrate_laser(
        H, d, ds.manifest["r_nominal"], ds.manifest["l_nominal"],
        groups=g, linearity_terms=lc.linearity_terms, distance_range_mm=(float(lo), float(hi)), limits=lc,
    )
    quality: dict[str, Any] = {
        "r_sigma_mm": res.r_sigma_mm.tolist(),
        "l_sigma_deg": res.l_sigma_deg.tolist(),
        "rms_mm": res.rms_mm,
        "max_residual_mm": res.max_residual_mm,
        "direction_spread_deg": list(res.direction_spread_deg),
        "readings_used": res.n_poses,
        "readings_without_value": dropped,
        "groups": int(g.max()) + 1 if len(g) else 0,
        "plane_normal": res.plane_normal.tolist(),
        "plane_offsets_mm": res.plane_offsets_mm.tolist(),
        "plane_known": res.plane_known,
        "linearity_terms": lc.linearity_terms,
        "linearity_coefficients_mm": res.linearity_coefficients_mm.tolist(),
    }
    warnings = []
    if dropped > 0.2 * len(rows):
        warnings.append(f"{dropped} of {len(rows)} readings had no value; check the aim point and the sensor's range")
    truth = ds.manifest.get("twin_truth")
    if truth and "r" in truth:
        rt, ltrue = np.asarray(truth["r"], float), np.asarray(truth["l"], float)
        quality["twin_truth"] = {
            "r_error_mm": float(np.linalg.norm(res.r - rt)),
            "r_error_components_mm": (res.r - rt).tolist(),
            "l_error_deg": float(np.degrees(angle_between_vectors(res.l, ltrue))),
        }
    method = "plane constraint, Levenberg-Marquardt, |l| = 1, plane estimated" + (
        f", sensor linearity modelled ({lc.linearity_terms} Legendre terms)" if lc.linearity_terms else ""
    )
    return Outcome("laser", method, {"r": res.r.tolist(), "l": res.l.tolist()}, quality, warnings, {}, res)


# -- nine-point and scale -----------------------------------------------------------------------


def compute_nine_point(ds: Dataset, cal: CalibrationSet | None, config: CellConfig) -> Outcome:
    """The nine-point map and the pixel scale s from a nine_point dataset."""
    npc = config.calibration.procedure.nine_point
    camera_id = _need(cal, "pixel_map", "camera")
    assert cal is not None
    recipe = parts_of(cal, ds.manifest.get("recipe"), config.default_recipe)  # the map goes with the teaching it is of
    teaching_id = _need(cal, "pixel_map", "teaching", recipe)
    lens = cal.lens()
    taught = cal.taught(recipe)
    views = ds.manifest["views"]
    corners, poses, quality_px = [], [], []
    feature = shot_feature(config)
    for v in views:
        m = detect_feature(ds.image(v["image"]), lens, config.vision, feature.arc, corner_radius=feature.corner_radius)
        if m.features is None:
            raise CalibrationRefused("pixel_map", "corner_not_found", f"{v['name']}: the {m.kind} detector refused: {m.message}")
        corners.append([m.features.u_px, m.features.v_px])
        poses.append(pose_array(v["T_B_H"], f"{v['name']}.T_B_H"))
        quality_px.append(m.sigma_px)
    offsets = offsets_from_poses(poses, taught.C_Pos_0, taught.T0)
    try:
        amap = nine_point_map(np.asarray(corners), offsets)
        amap.check(npc.max_rms_mm)
    except NinePointError as err:
        raise CalibrationRefused("pixel_map", "nine_point", str(err)) from None
    b = ds.manifest["scale_board"]
    try:
        scale = checkerboard_scale(ds.image(ds.manifest["scale_image"]), lens, tuple(b["inner_corners"]), float(b["square_mm"]))
    except ScaleCalibrationError as err:
        raise CalibrationRefused("pixel_map", "board_not_found", f"pixel scale: {err}") from None
    s = scale.mm_per_px
    agree = accept_nine_point_map(amap, s)  # mirrored or off the scale s: refused
    quality: dict[str, Any] = {
        "map_rms_mm": amap.rms_mm,
        "map_max_mm": amap.max_mm,
        "map_residuals_mm": amap.residuals_mm.tolist(),
        "map_mm_per_px": amap.mm_per_px,
        "map_rotation_deg": float(np.degrees(amap.rotation_rad)),
        "corner_sigma_px": quality_px,
        "offsets_mm": offsets.tolist(),
        "scale_mm_per_px": s,
        "scale_pairs": scale.n_pairs,
        "scale_ratio_std": scale.ratio_std,
        "scale_anisotropy": scale.anisotropy,
        "map_vs_scale": agree,
    }
    warnings = []
    if agree > 0.005:
        warnings.append(
            f"the nine-point map's scale ({amap.mm_per_px:.6f} mm/px) and the checkerboard's ({s:.6f} mm/px) differ by "
            f"{agree:.2%}: is the checkerboard flat on the wall, and the camera at the taught pose?"
        )
    return Outcome(
        "pixel_map",
        "nine-point by robot moves over the window corner (vision.fit_affine_map); scale by eq. 15 (vision.checkerboard_scale)",
        {"affine": amap.matrix.tolist(), "scale_mm_per_px": s},
        quality,
        warnings,
        {"camera": camera_id, "teaching": teaching_id},
        (amap, scale),
        recipe,
    )


# -- teaching -----------------------------------------------------------------------------------


def _taught_install(ds: Dataset, config: CellConfig, T0: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
    """g_Pos_0: the mean of the hand-guided installs, and how far the installs lie from it.

    The spread is measured where it matters, at the window corner (T0's origin): the largest
    distance by which an install moves the corner from where the mean puts it (an orientation
    difference of 0.02 deg moves the flange, 1.3 m from the corner, by 0.4 mm but the corner
    hardly at all), and the largest angle between an install and the mean. Installs spread
    beyond the configured limits are refused. A dataset from before repeated installs (one
    ``g_Pos_0``, no ``g_Pos_0_installs``) counts as one install.
    """
    tc = config.calibration.procedure.teach
    rows = ds.manifest.get("g_Pos_0_installs") or [ds.manifest["g_Pos_0"]]
    installs = np.array([pose_array(p, f"g_Pos_0_installs[{k}]") for k, p in enumerate(rows)])
    g_Pos_0 = mean_pose(installs)
    corner = np.append(T0[:3, 3], 1.0)
    moved = [h @ invert_pose(g_Pos_0) @ corner for h in installs]
    spread_mm = max(float(np.linalg.norm(m[:3] - corner[:3])) for m in moved)
    spread_deg = max(float(np.degrees(rotation_angle_between(g_Pos_0[:3, :3], h[:3, :3]))) for h in installs)
    if spread_mm > tc.max_install_spread_mm or spread_deg > tc.max_install_spread_deg:
        raise CalibrationRefused(
            "teaching", "install_spread",
            f"the {len(installs)} hand-guided installs put the window corner up to {spread_mm:.3f} mm and the glass up to "
            f"{spread_deg:.4f} deg from their mean (limits {tc.max_install_spread_mm:g} mm, {tc.max_install_spread_deg:g} deg): "
            "guide the glass in again, more carefully, or check that the car body did not move between the installs",
        )
    return g_Pos_0, {"count": len(installs), "spread_mm": spread_mm, "spread_deg": spread_deg}


def align_for_teaching(
    H: np.ndarray, d: np.ndarray, stops: list[int], cal: CalibrationSet, config: CellConfig, start: np.ndarray,
    range_mm: tuple[float, float],
) -> AlignmentResult:
    """Teaching's laser alignment (paper 3) from spots read standing, from the flange pose ``start``; the spots
    ``stops`` (a sweep path's corners) give the wall's distance, as the cycle on the move takes it at its stops."""
    ac = config.process.align
    r, l = cal.laser_ray()  # noqa: E741
    try:
        return compute_alignment(
            H, d, r, l, cal.T_H_C(), config.process.working_distance_mm, T_B_H_current=start, range_mm=range_mm,
            inlier_threshold_mm=ac.inlier_threshold_mm, max_rms_mm=ac.max_rms_mm, min_collinearity=ac.min_collinearity,
            at_rest=readings_at_stops(H, d, stops), min_rest_points=len(stops),
        )  # fmt: skip
    except AlignmentError as err:
        raise CalibrationRefused("teaching", "alignment", str(err)) from None


def compute_teaching(ds: Dataset, cal: CalibrationSet | None, config: CellConfig) -> Outcome:
    """T0, C_Pos_0, the template and g_Pos_0 from a teaching dataset and the calibrated sensors."""
    ids = {n: _need(cal, "teaching", n) for n in ("camera", "hand_eye", "laser")}
    assert cal is not None
    T_H_C = cal.T_H_C()
    spots = ds.manifest["spots"]
    H = np.array([pose_array(s["T_B_H"], "spot.T_B_H") for s in spots])
    d = np.array([s["distance_mm"] for s in spots], dtype=float)
    start = pose_array(ds.manifest["shooting_start"], "shooting_start")
    refuse_changed_shot(ds.manifest, config)
    stops = [k for k, s in enumerate(spots) if s.get("stop")]  # taught for the cycle on the move: its corners
    align = align_for_teaching(H, d, stops, cal, config, start, tuple(ds.manifest["sensor_range_mm"]))
    C_Pos_0 = pose_array(ds.manifest["C_Pos_0"], "C_Pos_0")
    moved_mm, moved_rad = pose_error(align.T_B_H_aligned, C_Pos_0)
    if np.linalg.norm(moved_mm) > 1.0 or np.linalg.norm(moved_rad) > np.radians(0.05):
        raise CalibrationRefused(
            "teaching", "pose_mismatch",
            f"the image was taken {np.linalg.norm(moved_mm):.2f} mm / {np.degrees(np.linalg.norm(moved_rad)):.3f} deg away "
            "from the aligned shooting pose these laser readings give; the dataset does not belong together",
        )
    lens = cal.lens()
    feature = shot_feature(config)
    shot = detect_feature(ds.image(ds.manifest["shooting_image"]), lens, config.vision, feature.arc, corner_radius=feature.corner_radius)
    if shot.features is None:
        raise CalibrationRefused("teaching", "corner_not_found", f"the {shot.kind} detector refused the template image: {shot.message}")
    f = shot.features
    plane = align.wall.plane
    T_feature = workpiece_frame_from_corner(
        C_Pos_0, T_H_C, cal.camera_matrix(), [f.u_px, f.v_px], f.theta_rad, plane.normal, plane.offset
    )
    T0 = T_feature @ make_pose(np.eye(3), [-feature.point_mm[0], -feature.point_mm[1], 0.0])  # the feature lies at point_mm in T0
    g_Pos_0, installs = _taught_install(ds, config, T0)
    nominal = pose_array(ds.manifest["T0_nominal"], "T0_nominal")
    dn, rn = deviation_in_frame(nominal, T0)
    quality: dict[str, Any] = {
        "wall_rms_mm": plane.rms,
        "spots_used": int(len(align.wall.inliers)),
        "offset_from_stops": len(stops),  # 0: the wall's offset from all spots; else from the sweep's corners, as on the move
        "spots_rejected": [{"index": s.index, "reason": s.reason} for s in align.wall.rejected],
        "normal_uncertainty_deg": None if align.wall.uncertainty is None else float(np.degrees(align.wall.uncertainty.rms_rad)),
        "alignment_turn_deg": float(np.degrees(align.rotation_rad)),
        "distance_correction_mm": align.distance.delta_d_mm,
        "feature": shot.kind,
        "corner_sigma_px": shot.sigma_px,
        "corner_angle_deg": corner_angle_deg(shot.measurement),
        "corner_checks": [{"name": c.name, "value": c.value, "limit": c.limit, "ok": c.passed} for c in shot.measurement.checks],
        "feature_edge": taught_feature(shot.measurement, config),
        "T0_from_layout_mm": dn.tolist(),
        "T0_from_layout_deg": np.degrees(rn).tolist(),
        "operator": ds.manifest.get("operator", {}),
        "g_Pos_0_installs": installs,
    }
    truth = ds.manifest.get("twin_truth")
    if truth:
        Tt = np.asarray(truth["T_B_T"], dtype=float)
        dt, dr = deviation_in_frame(Tt, T0)
        quality["twin_truth"] = {
            "T0_error_mm": dt.tolist(),
            "T0_error_deg": np.degrees(dr).tolist(),
            "g_Pos_0_install_error": truth.get("g_Pos_0_install_error"),
        }
    values = {
        "recipe": ds.manifest.get("recipe") or config.default_recipe,
        "wall_read": ds.manifest.get("wall_read"),  # None in a dataset from before it was recorded
        "shot": taught_shot(config),
        "profile": taught_profile(shot.measurement, config.vision.feature),  # each shot's feature is found again by it
        "T0": T0.tolist(),
        "C_Pos_0": C_Pos_0.tolist(),
        "g_Pos_0": g_Pos_0.tolist(),
        "u_d": f.u_px,
        "v_d": f.v_px,
        "theta_d": f.theta_rad,
        "top_angle_d": f.top_angle_rad if np.isfinite(f.top_angle_rad) else None,  # None: not in view (an arc corner)
        "right_angle_d": f.right_angle_rad if np.isfinite(f.right_angle_rad) else None,
    }
    return Outcome(
        "teaching",
        "laser alignment (paper 3) at the standing car body, corner template (paper 4.2), T0 from corner ray and wall, "
        "g_Pos_0 as the mean of hand-guided installs",
        values,
        quality,
        [],
        ids,
        (align, shot.measurement, T0),
        recipe_slot(ds.manifest.get("recipe"), config.default_recipe),
    )


__all__ = ["Outcome", "compute_camera", "compute_hand_eye", "compute_laser", "compute_nine_point", "compute_teaching", "detect_views"]
