"""The arc detector on the twin's own renders (issue 21): a 150 mm corner of a real opening.

``cellctl bench arc-corner --renderer twin``: each render is a new car body of config/sim.toml's
door window (1200 x 900 mm, 150 mm corners; ``--radius-mm`` another radius, the shot measured by
the method and aim that radius gives: cellctl.config.feature) with its own drawn surface (paint edge, wall's edge,
flange, seal: concentric arcs), seen from the recipe's shooting pose shifted by up to 10 mm and
turned by up to 1 deg, through the twin's camera (lens, blur, vignetting, shot and read noise). A
share of the renders carries the twin's glare on the straight edge in view. The detector runs with
the recipe's own settings (cellctl.config.feature.arc_corner_config). Truth: the arc's centre
projected through the true camera pose (the corner method's: the wall edge's virtual sharp corner);
errors in square px (fx on both axes).
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from typing import Any

import cv2
import numpy as np

from cellctl.config import load_config
from cellctl.config.feature import arc_corner_config, corner_radius, feature_kind, shot_aim_mm
from cellctl.config.schema import CellConfig
from cellctl.config.render import DisturbanceConfig, GlareConfig
from cellctl.geometry.pose import apply_pose, invert_pose
from cellctl.geometry.rotation import rot_z
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.image_truth import camera_pose_seeing_corner
from cellctl.sim.world import sample_world
from cellctl.bench.stats import percentile
from cellctl.vision.arc_corner import detect_arc_corner
from cellctl.vision.corner import detect_corner
from cellctl.vision.lens import Lens

RECIPE = "door-window"
WRONG_PX = 1.0
GLARE_SHARE = 0.3
SHIFT_MM = 10.0
TURN_DEG = 1.0


def with_radius(config: CellConfig, radius_mm: float) -> CellConfig:
    """``config`` with ``layout.opening.corner_radius_mm`` replaced (the method, aim and settings follow it)."""
    opening = config.layout.opening.model_copy(update={"corner_radius_mm": float(radius_mm)})
    return config.model_copy(update={"layout": config.layout.model_copy(update={"opening": opening})})


def run_arc_corner_twin(
    n: int, seed: int, config_path: str = "config/sim.toml", radius_mm: float | None = None
) -> dict[str, Any]:
    """Render ``n`` seeded frames of the twin's corner (150 mm, or ``radius_mm``), detect each, return the figures."""
    cv2.setNumThreads(1)
    config = load_config(config_path).for_recipe(RECIPE)
    if radius_mm is not None:
        config = with_radius(config, radius_mm)
    method = feature_kind(config)
    sim = config.sim
    arc = arc_corner_config(config) if method == "arc" else None
    expected = corner_radius(config)
    lens = Lens.from_intrinsics(sim.camera.intrinsics)
    K = lens.camera_matrix
    clean = CameraRenderer(sim.camera.intrinsics, sim.camera.render)
    glare_cfg = sim.camera.render.model_copy(update={"disturbances": DisturbanceConfig(glare=GlareConfig())})
    glary = CameraRenderer(sim.camera.intrinsics, glare_cfg)
    r_mm = float(config.layout.opening.corner_radius_mm)
    aim = shot_aim_mm(config)
    rng = np.random.default_rng(seed)
    errors: dict[str, list[float]] = {"clean": [], "glare": []}
    refusals: Counter[str] = Counter()
    wrong: list[dict[str, Any]] = []
    theta_err: list[float] = []
    for i in range(n):
        kind = "glare" if rng.uniform() < GLARE_SHARE else "clean"
        world = sample_world(sim.world, rng)
        world = dataclasses.replace(world, width_mm=1200.0, height_mm=900.0, corner_radius_mm=r_mm)
        # The aim point at the image centre, then the body's placement error: a shift and a turn.
        shift = rng.uniform(-SHIFT_MM, SHIFT_MM, 2)
        turn = np.radians(rng.uniform(-TURN_DEG, TURN_DEG))
        aim_px = np.array([lens.cx, lens.cy]) + (np.array([-aim[0], -aim[1]]) + shift) * np.array([K[0, 0], K[1, 1]]) / 400.0
        renderer = glary if kind == "glare" else clean
        T_B_C = camera_pose_seeing_corner(renderer.camera, world, tuple(lens.distort(aim_px[None])[0]), distance_mm=400.0,
                                          R_T_C=rot_z(turn))  # fmt: skip
        frame = renderer.render(T_B_C, world, rng=rng)
        if arc is not None:
            a = detect_arc_corner(frame.image, lens, arc)
            refusal, point, theta = a.refusal, a.centre_px, a.orientation.theta_rad if a.orientation else None
            checks, message = a.checks, a.message
        else:
            c = detect_corner(frame.image, lens, config.vision, expected)
            refusal, point, theta, checks, message = c.refusal, c.corner_px, c.theta_rad, c.checks, c.message
        if refusal is not None or point is None:
            failed = next((ch.name for ch in checks if not ch.passed), message)
            refusals[f"{refusal.value if refusal else '?'}: {failed}"] += 1
            continue
        # The feature point (the arc's centre, or the virtual corner) and two points of the top edge beyond the
        # arc, through the true camera pose.
        feature = [-r_mm, r_mm, 0.0] if arc is not None else [0.0, 0.0, 0.0]
        q = apply_pose(invert_pose(T_B_C), apply_pose(world.T_B_T, np.array([feature, [-r_mm - 300.0, 0.0, 0.0],
                                                                              [-r_mm - 100.0, 0.0, 0.0]])))  # fmt: skip
        px = np.column_stack([K[0, 0] * q[:, 0] / q[:, 2] + K[0, 2], K[1, 1] * q[:, 1] / q[:, 2] + K[1, 2]])
        truth, top = px[0], px[2] - px[1]
        err = float(np.hypot(*(lens.to_square(point)[0] - lens.to_square(truth)[0])))
        errors[kind].append(err)
        if err > WRONG_PX:
            wrong.append({"render": i, "kind": kind, "error_px": round(err, 3)})
        if theta is not None:
            theta_err.append(abs(float(np.degrees(theta - np.arctan2(top[1], top[0])))))
    every = errors["clean"] + errors["glare"]
    return {
        "renderer": "twin",
        "renders": n,
        "seed": seed,
        "radius_mm": r_mm,
        "method": method,
        "accepted": len(every),
        "accepted_by_kind": {k: len(v) for k, v in errors.items()},
        "centre_error_px": {"median": percentile(every, 50), "p95": percentile(every, 95), "p99": percentile(every, 99),
                            "max": max(every) if every else float("nan")},
        "clean_centre_error_px": {"median": percentile(errors["clean"], 50), "p99": percentile(errors["clean"], 99)},
        "refusals": dict(refusals.most_common()),
        "wrong_answers": wrong,
        "orientation_answers": len(theta_err),
        "orientation_error_deg": {"median": percentile(theta_err, 50), "max": max(theta_err) if theta_err else float("nan")},
        "bar_met": bool(every) and percentile(every, 50) <= 0.1 and percentile(every, 99) <= 0.3 and not wrong,
    }


def format_arc_corner_twin(out: dict[str, Any], wall_s: float) -> str:
    """The figures of :func:`run_arc_corner_twin` as the report's lines."""
    e, c, o = out["centre_error_px"], out["clean_centre_error_px"], out["orientation_error_deg"]
    return "\n".join([
        f"arc corner bench on the twin's renders: {out['renders']} renders (seed {out['seed']}), {out['accepted']} accepted "
        f"{out['accepted_by_kind']}; the door window's {out['radius_mm']:g} mm corner with its drawn surface, "
        f"measured by the {out['method']} method",
        *(f"  {'centre' if out['method'] == 'arc' else 'corner'} error {name:6s} {e[name]:.4f} px" for name in ("median", "p95", "p99", "max")),
        f"  without glare: median {c['median']:.4f} px, p99 {c['p99']:.4f} px",
        "  refusals by reason:",
        *(f"    {count:4d}  {reason}" for reason, count in out["refusals"].items()),
        f"  wrong answers (accepted > {WRONG_PX:g} px off): {len(out['wrong_answers'])}",
        *(f"    {w}" for w in out["wrong_answers"]),
        f"  orientation given {out['orientation_answers']} times: error median {o['median']:.4f} deg, max {o['max']:.4f} deg",
        f"  wall time {wall_s:.1f} s",
        f"  bar (median <= 0.1 px, p99 <= 0.3 px, no wrong answer): {'met' if out['bar_met'] else 'NOT met'}",
    ])
