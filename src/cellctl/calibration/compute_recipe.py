"""A recipe's own calibration parts from their datasets: the nine-point map with the pixel scale, and teaching.

As :mod:`cellctl.calibration.compute` (the cell's parts: camera, hand-eye, laser), each reads only its dataset and
the calibration set it builds on, and gives an :class:`~cellctl.calibration.compute.Outcome`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cellctl.align import AlignmentError, AlignmentResult, compute_alignment, readings_at_stops
from cellctl.calibration.calibration_set import CalibrationSet, parts_of, recipe_slot
from cellctl.calibration.compute import Outcome, need_part
from cellctl.calibration.dataset import Dataset, pose_array
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.pixel_map import accept_nine_point_map, nine_point_map, offsets_from_poses
from cellctl.calibration.taught_shot import refuse_changed_shot, taught_profile, taught_shot
from cellctl.calibration.teach import workpiece_frame_from_corner
from cellctl.calibration.template_figures import corner_angle_deg, taught_feature
from cellctl.compensate import deviation_in_frame
from cellctl.config.feature import shot_feature
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import invert_pose, make_pose, mean_pose, pose_error
from cellctl.geometry.rotation import rotation_angle_between
from cellctl.vision.feature import detect_feature
from cellctl.vision.ninepoint import NinePointError
from cellctl.vision.scale import ScaleCalibrationError, checkerboard_scale

# -- nine-point and scale -----------------------------------------------------------------------


def compute_nine_point(ds: Dataset, cal: CalibrationSet | None, config: CellConfig) -> Outcome:
    """The nine-point map and the pixel scale s from a nine_point dataset."""
    npc = config.calibration.procedure.nine_point
    camera_id = need_part(cal, "pixel_map", "camera")
    assert cal is not None
    recipe = parts_of(cal, ds.manifest.get("recipe"), config.default_recipe)  # the map goes with the teaching it is of
    teaching_id = need_part(cal, "pixel_map", "teaching", recipe)
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
    ids = {n: need_part(cal, "teaching", n) for n in ("camera", "hand_eye", "laser")}
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


__all__ = ["align_for_teaching", "compute_nine_point", "compute_teaching"]
