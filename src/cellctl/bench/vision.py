"""Benchmark of the window-corner detector (paper 4.2) against the twin's truth, on one core.

Run ``python -m cellctl.bench.vision``. Prints

- the median time to find the corner in one 2048 x 2048 frame, and its ratio to ``cv2.Canny``
  alone on the same frame (the configured thresholds, full resolution);
- the accuracy over ``--renders`` seeded renders with default noise: corner position error in the
  raw image (median, p99, max, px) and edge-angle error (median, p99, deg), against the limits
  (0.1 px median, 0.3 px p99, 0.02 deg median);
- the same for each disturbance (a glare spot on an edge, 30 % of one edge covered by a
  wall-coloured or a dark strip, half the contrast, defocus) over ``--disturbed-renders`` renders,
  against twice those limits, counting refusals by reason and any corner accepted more than
  1 px off.

Each render places the car body at a random posture and the camera at a shooting pose after
alignment: square to the wall within 0.3 deg, 400 +- 1 mm away, turned up to 2 deg about its
axis, with the corner up to 20 mm (262 px) from the image centre.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Callable

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from cellctl.config.render import DisturbanceConfig, GlareConfig, OcclusionConfig, RenderConfig  # noqa: E402
from cellctl.config.sim import SimConfig  # noqa: E402
from cellctl.config.vision import VisionConfig  # noqa: E402
from cellctl.geometry.rotation import rot_x, rot_y, rot_z  # noqa: E402
from cellctl.sim.camera import CameraRenderer  # noqa: E402
from cellctl.sim.image_truth import camera_pose_seeing_corner, corner_truth  # noqa: E402
from cellctl.sim.world import World, sample_world  # noqa: E402
from cellctl.vision.corner import detect_corner  # noqa: E402
from cellctl.vision.lens import Lens  # noqa: E402

# Limits of issue 4 (default noise); disturbances are held to twice these.
MEDIAN_LIMIT_PX = 0.1
P99_LIMIT_PX = 0.3
ANGLE_MEDIAN_LIMIT_DEG = 0.02
NEVER_ACCEPT_PX = 1.0

DISTURBANCES: dict[str, DisturbanceConfig] = {
    "glare spot on an edge": DisturbanceConfig(glare=GlareConfig()),
    "30 % of an edge covered (wall-like)": DisturbanceConfig(occlusion=OcclusionConfig(kind="wall_like")),
    "30 % of an edge covered (dark)": DisturbanceConfig(occlusion=OcclusionConfig(kind="dark")),
    "half contrast": DisturbanceConfig(contrast_factor=0.5),
    "defocus (+1.5 px blur)": DisturbanceConfig(defocus_sigma_px=1.5),
}


def shooting_scene(renderer: CameraRenderer, sim: SimConfig, rng: np.random.Generator) -> tuple[World, NDArray[np.float64]]:
    """A car body at a random posture and the camera at an aligned shooting pose in front of its corner."""
    world = sample_world(sim.world, rng)
    intr = sim.camera.intrinsics
    offset_px = 20.0 * intr.fx / 400.0  # 20 mm at the working distance
    corner = (intr.cx + rng.uniform(-offset_px, offset_px), intr.cy + rng.uniform(-offset_px, offset_px))
    tilt = np.radians(0.3)
    R = rot_x(rng.uniform(-tilt, tilt)) @ rot_y(rng.uniform(-tilt, tilt)) @ rot_z(np.radians(rng.uniform(-2.0, 2.0)))
    pose = camera_pose_seeing_corner(renderer.camera, world, corner, distance_mm=400.0 + rng.uniform(-1.0, 1.0), R_T_C=R)
    return world, pose


@dataclass
class Accuracy:
    """Errors of accepted corners against the truth, and the refusals."""

    renders: int = 0
    corner_err_px: list[float] = field(default_factory=list)
    angle_err_deg: list[float] = field(default_factory=list)
    refusals: Counter[str] = field(default_factory=Counter)

    @property
    def accepted(self) -> int:
        return len(self.corner_err_px)

    def figures(self) -> dict[str, float]:
        c = np.asarray(self.corner_err_px)
        a = np.asarray(self.angle_err_deg)
        if len(c) == 0:
            return {"median": float("nan"), "p99": float("nan"), "max": float("nan"), "angle_median": float("nan"), "angle_p99": float("nan")}
        return {
            "median": float(np.median(c)),
            "p99": float(np.percentile(c, 99)),
            "max": float(np.max(c)),
            "angle_median": float(np.median(a)),
            "angle_p99": float(np.percentile(a, 99)),
        }

    def meets(self, factor: float) -> bool:
        f = self.figures()
        if self.accepted == 0:
            return True  # everything refused: no wrong corner was returned
        return (
            f["median"] <= factor * MEDIAN_LIMIT_PX
            and f["p99"] <= factor * P99_LIMIT_PX
            and f["angle_median"] <= factor * ANGLE_MEDIAN_LIMIT_DEG
            and f["max"] <= NEVER_ACCEPT_PX
        )


def measure_accuracy(
    renderer: CameraRenderer, sim: SimConfig, lens: Lens, config: VisionConfig, renders: int, rng: np.random.Generator
) -> Accuracy:
    """Render ``renders`` shooting views, detect the corner and compare with the twin's truth."""
    acc = Accuracy()
    for _ in range(renders):
        world, pose = shooting_scene(renderer, sim, rng)
        frame = renderer.render(pose, world, rng=rng)
        m = detect_corner(frame.image, lens, config)
        acc.renders += 1
        if not m.ok:
            acc.refusals[m.refusal.value if m.refusal else "?"] += 1
            continue
        truth = corner_truth(renderer.camera, pose, world)
        assert m.corner_raw_px is not None and m.top is not None and m.right is not None
        acc.corner_err_px.append(float(np.linalg.norm(m.corner_raw_px - truth.corner_px)))
        right_truth = float(np.arctan2(-truth.right_edge_dir_px[0], truth.right_edge_dir_px[1]))
        acc.angle_err_deg.append(abs(float(np.degrees(m.top.angle_rad - truth.edge_angle_rad))))
        acc.angle_err_deg.append(abs(float(np.degrees(m.right.angle_rad - right_truth))))
    return acc


def _median_s(fn: Callable[[], object], runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _report(name: str, acc: Accuracy, factor: float) -> None:
    f = acc.figures()
    refused = ", ".join(f"{k} {v}" for k, v in sorted(acc.refusals.items())) or "none"
    print(f"  {name}: {acc.accepted}/{acc.renders} accepted (refused: {refused})")
    print(
        f"    corner error median {f['median']:.4f} px, p99 {f['p99']:.4f} px, max {f['max']:.4f} px; "
        f"edge angle error median {f['angle_median']:.5f} deg, p99 {f['angle_p99']:.5f} deg"
    )
    print(
        f"    limits x{factor:g} (median {factor * MEDIAN_LIMIT_PX:g} px, p99 {factor * P99_LIMIT_PX:g} px, "
        f"angle {factor * ANGLE_MEDIAN_LIMIT_DEG:g} deg, none accepted > {NEVER_ACCEPT_PX:g} px): "
        f"{'met' if acc.meets(factor) else 'NOT met'}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m cellctl.bench.vision", description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=30, help="timed detections of one frame (default 30)")
    parser.add_argument("--renders", type=int, default=200, help="renders for the default-noise accuracy (default 200)")
    parser.add_argument("--disturbed-renders", type=int, default=100, help="renders per disturbance (default 100)")
    parser.add_argument("--seed", type=int, default=2026)
    args = parser.parse_args(argv)
    if args.runs < 1 or args.renders < 1 or args.disturbed_renders < 0:
        parser.error("--runs and --renders must be at least 1, --disturbed-renders at least 0")
    cv2.setNumThreads(1)
    sim = SimConfig()
    config = VisionConfig()
    lens = Lens.from_intrinsics(sim.camera.intrinsics)
    renderer = CameraRenderer(sim.camera.intrinsics, sim.camera.render)
    rng = np.random.default_rng(args.seed)

    world, pose = shooting_scene(renderer, sim, rng)
    image = renderer.render(pose, world, rng=rng).image
    detect_corner(image, lens, config)  # warm-up
    detect_s = _median_s(lambda: detect_corner(image, lens, config), args.runs)
    c = config.coarse
    canny_s = _median_s(lambda: cv2.Canny(image, c.canny_low, c.canny_high, L2gradient=c.canny_l2_gradient), args.runs)
    print(f"window-corner detector, {image.shape[1]} x {image.shape[0]} 8-bit, one core, seed {args.seed}")
    print(f"  median detection time ({args.runs} runs)        {detect_s * 1e3:8.1f} ms")
    print(f"  cv2.Canny alone on the same frame            {canny_s * 1e3:8.1f} ms")
    print(f"  ratio detection / Canny                      {detect_s / canny_s:8.2f} x")
    print(f"  target <= 50 ms: {'met' if detect_s <= 0.05 else 'NOT met'}")

    print("accuracy against the twin's truth (raw image, corner error = distance to the true corner):")
    acc = measure_accuracy(renderer, sim, lens, config, args.renders, rng)
    _report(f"default noise, {args.renders} renders", acc, 1.0)
    all_met = acc.meets(1.0) and acc.accepted == acc.renders
    if acc.accepted != acc.renders:
        print("    (a clean frame was refused)")
    if args.disturbed_renders:
        for name, dist in DISTURBANCES.items():
            disturbed = CameraRenderer(sim.camera.intrinsics, RenderConfig(**{**sim.camera.render.model_dump(), "disturbances": dist}))
            d_acc = measure_accuracy(disturbed, sim, lens, config, args.disturbed_renders, rng)
            _report(f"{name}, {args.disturbed_renders} renders", d_acc, 2.0)
            all_met &= d_acc.meets(2.0)
    print(f"all accuracy limits: {'met' if all_met else 'NOT met'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
