"""The readable lines of a calibration outcome, written from its stored values and quality figures.

The computations (cellctl.calibration.compute) return numbers only; these lines are made from the
same dictionaries that are recorded, so a stored record reads the same as the fresh result.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

_TRUTH_NOTE = "(robot poses are the controller's beliefs: its accuracy and repeatability are in them)"


def _vec(v: Any, precision: int) -> str:
    """A vector as an engineer reads it: ``(1358.10, -1074.77, 1901.38)``, fixed decimals, no numpy layout."""
    return "(" + ", ".join(f"{x:.{precision}f}" for x in np.asarray(v, dtype=float).ravel()) + ")"


def _camera(values: dict[str, Any], q: dict[str, Any]) -> list[str]:
    K, std = np.asarray(values["K"], dtype=float), q["std"]
    lines = [
        f"fx {K[0, 0]:.2f} +- {std['fx']:.2f} px, fy {K[1, 1]:.2f} +- {std['fy']:.2f} px",
        f"cx {K[0, 2]:.2f} +- {std['cx']:.2f} px, cy {K[1, 2]:.2f} +- {std['cy']:.2f} px",
        "k1 k2 p1 p2 k3 " + " ".join(f"{v:.5g}" for v in np.ravel(values["dist"])),
        f"RMS reprojection {q['rms_px']:.4f} px over {q['views_used']} of {q['views_total']} views, "
        f"image coverage {q['coverage']:.0%}",
    ]
    if t := q.get("twin_truth"):
        lines.append(
            f"true error: fx {t['fx_error_pct']:+.4f} %, fy {t['fy_error_pct']:+.4f} %, "
            f"cx {t['cx_error_px']:+.3f} px, cy {t['cy_error_px']:+.3f} px"
        )
    return lines


def _hand_eye(values: dict[str, Any], q: dict[str, Any]) -> list[str]:
    chosen, methods, motion = q["chosen"], q["methods"], q["motion"]
    best = methods[chosen]
    lines = [
        f"T_H_C translation {_vec(np.asarray(values['T_H_C'])[:3, 3], 3)} mm ({chosen}, {q['views_used']} views, "
        f"{motion['pairs']} motion pairs)",
        f"residuals: AX=XB {best['residual_rotation_rms_deg']:.4f} deg / {best['residual_translation_rms_mm']:.3f} mm RMS, "
        f"board spread {best['board_spread_mm']:.3f} mm, chain reprojection {best['chain_reprojection_rms_px']:.3f} px",
        f"methods vs {chosen}: "
        + ", ".join(
            f"{m.replace('opencv_', 'cv2-')} {s['from_chosen_mm']:.3f} mm/{s['from_chosen_deg']:.4f} deg"
            for m, s in methods.items()
            if m != chosen
        ),
        f"motion: axis spread {motion['axis_spread']:.2f} (3-D {motion['axis_spread_3d']:.2f}), pair angles up to "
        f"{motion['max_pair_angle_deg']:.0f} deg",
    ]
    if t := q.get("twin_truth"):
        lines.append(
            f"true error: {t[chosen]['translation_error_mm']:.3f} mm, {t[chosen]['rotation_error_deg']:.4f} deg {_TRUTH_NOTE}"
        )
    return lines


def _laser(values: dict[str, Any], q: dict[str, Any]) -> list[str]:
    spread = q["direction_spread_deg"]
    lines = [
        f"r {_vec(values['r'], 4)} mm +- {_vec(q['r_sigma_mm'], 3)}",
        f"l {_vec(values['l'], 6)} +- {_vec(q['l_sigma_deg'], 4)} deg",
        f"plane residual {q['rms_mm']:.4f} mm RMS (max {q['max_residual_mm']:.4f}) over {q['readings_used']} readings "
        f"({q['readings_without_value']} without value), normal seen over {spread[0]:.1f} / {spread[1]:.1f} deg",
    ]
    if t := q.get("twin_truth"):
        lines.append(f"true error: r {t['r_error_mm']:.3f} mm, l {t['l_error_deg']:.4f} deg {_TRUTH_NOTE}")
    return lines


def _pixel_map(values: dict[str, Any], q: dict[str, Any]) -> list[str]:
    return [
        f"nine-point map: {q['map_mm_per_px']:.6f} mm/px, image u axis at {q['map_rotation_deg']:+.4f} deg in T0, "
        f"residual {q['map_rms_mm']:.4f} mm RMS (max {q['map_max_mm']:.4f})",
        f"pixel scale s (eq. 15) {q['scale_mm_per_px']:.6f} mm/px over {q['scale_pairs']} corner pairs "
        f"(spread {q['scale_ratio_std']:.2e}); map and s differ by {q['map_vs_scale']:.3%}",
    ]


def _teaching(values: dict[str, Any], q: dict[str, Any]) -> list[str]:
    installs = q["g_Pos_0_installs"]
    edges = q.get("feature_edge", {})
    lines = [
        f"wall fit {q['wall_rms_mm']:.4f} mm RMS over {q['spots_used']} spots"
        + (f", its distance at the sweep's {q['offset_from_stops']} stops" if q.get("offset_from_stops") else "")
        + "; C_Pos_0 at "
        f"{_vec(np.asarray(values['C_Pos_0'])[:3, 3], 2)} mm",
        f"template: u_d {values['u_d']:.3f} px, v_d {values['v_d']:.3f} px, theta_d {np.degrees(values['theta_d']):+.4f} deg "
        f"(corner sigma {q['corner_sigma_px']:.3f} px)",
        "feature edge: "
        + "; ".join(
            f"{name} edge step {edges[name]['feature']} of the {len(edges[name]['steps'])} found across it (0 the outermost)"
            for name in ("top", "right")
            if name in edges
        ),
        f"T0 at {_vec(np.asarray(values['T0'])[:3, 3], 2)} mm, {np.linalg.norm(q['T0_from_layout_mm']):.2f} mm from the "
        "layout's nominal corner",
        f"g_Pos_0 at {_vec(np.asarray(values['g_Pos_0'])[:3, 3], 2)} mm, the mean of {installs['count']} hand-guided "
        f"install{'s' if installs['count'] != 1 else ''} (corner within {installs['spread_mm']:.3f} mm, glass within {installs['spread_deg']:.4f} deg of it)",
    ]
    if t := q.get("twin_truth"):
        ie = t.get("g_Pos_0_install_error") or {}
        lines.append(
            f"true error: T0 {_vec(t['T0_error_mm'], 3)} mm, {_vec(t['T0_error_deg'], 4)} deg; glass at g_Pos_0 off by "
            f"({ie.get('dx_mm', float('nan')):+.3f}, {ie.get('dy_mm', float('nan')):+.3f}, "
            f"{ie.get('dz_mm', float('nan')):+.3f}) mm"
        )
    return lines


def _verify(values: dict[str, Any], q: dict[str, Any]) -> list[str]:
    he, lim = q["hand_eye"], q["limits"]
    lines = [
        f"hand-eye: {he['translation_mm']:.3f} mm, {he['rotation_deg']:.4f} deg from the stored calibration's data "
        f"({he['views']} views; limits {lim['max_hand_eye_mm']:g} mm, {lim['max_hand_eye_deg']:g} deg)"
    ]
    if la := q.get("laser"):
        lines.append(
            f"laser: r {la['r_mm']:.3f} mm, l {la['l_deg']:.4f} deg ({la['readings']} readings; limits "
            f"{lim['max_laser_r_mm']:g} mm, {lim['max_laser_l_deg']:g} deg)"
        )
    beyond = q["beyond_limits"]
    lines.append("within limits: the stored calibration still holds" if not beyond else "DRIFT: " + "; ".join(beyond))
    return lines


_WRITERS: dict[str, Callable[[dict[str, Any], dict[str, Any]], list[str]]] = {
    "camera": _camera,
    "hand_eye": _hand_eye,
    "laser": _laser,
    "pixel_map": _pixel_map,
    "teaching": _teaching,
    "verify": _verify,
}


def summary_lines(part: str, values: dict[str, Any], quality: dict[str, Any]) -> list[str]:
    """The outcome of ``part`` in a few lines, from its values and quality figures."""
    writer = _WRITERS.get(part)
    return writer(values, quality) if writer is not None else []
