"""From a saved dataset to a calibration part: the offline half of every calibration command.

Each ``compute_*`` reads only the dataset (and, where a part builds on others, the current
calibration set), so any calibration can be recomputed later from its folder and compared. The
result is an :class:`Outcome`: the values for the calibration set, the quality figures, warnings,
the ids of the parts used, and a few readable summary lines. Data that cannot give a trustworthy
result raises CalibrationRefused with the reason.

The cell's parts are here (camera, hand-eye, laser); a recipe's own (nine-point, teaching) are in
:mod:`cellctl.calibration.compute_recipe`.

A dataset recorded in the simulated cell carries the simulator's truth under ``twin_truth``; it
is never used in a computation, only compared with the result afterwards (``quality.twin_truth``),
so a simulated run reports its true error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cellctl.calibration.board import BoardDetection, BoardSpec, find_board
from cellctl.calibration.calibration_set import CalibrationSet
from cellctl.calibration.camera import ViewCorners, calibrate_camera
from cellctl.calibration.dataset import Dataset, pose_array
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.hand_eye import board_pose, refuse_disagreement, solve_hand_eye
from cellctl.calibration.laser import calibrate_laser
from cellctl.calibration.summary import summary_lines
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import check_pose
from cellctl.geometry.rotation import angle_between_vectors, rotation_angle_between


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


def need_part(cal: CalibrationSet | None, part: str, name: str, recipe: str | None = None) -> str:
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
    camera_id = need_part(cal, "hand_eye", "camera")
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


__all__ = ["Outcome", "compute_camera", "compute_hand_eye", "compute_laser", "detect_views", "need_part"]
