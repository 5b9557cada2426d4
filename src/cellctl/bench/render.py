"""Benchmark of the twin camera: median time to render one 2048 x 2048 frame, on one core.

Run ``python -m cellctl.bench.render``. Prints the median over ``--runs`` frames of the shooting
view (the window corner in view, default noise, a new car-body posture and camera pose per frame),
its ratio to a trivial baseline (cv2.GaussianBlur of one 8-bit frame, sigma 1), the split between
shading and the sensor stage, the one-off cost of the cached ray map, and a checkerboard frame.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from cellctl.bench.timing import median_s  # noqa: E402
from cellctl.config.render import DisturbanceConfig, GlareConfig, OcclusionConfig, RenderConfig  # noqa: E402
from cellctl.config.sim import SimConfig  # noqa: E402
from cellctl.geometry.pose import make_pose  # noqa: E402
from cellctl.geometry.rotation import rot_x, rot_y, rot_z  # noqa: E402
from cellctl.sim import camera_model  # noqa: E402
from cellctl.sim.camera import CameraRenderer  # noqa: E402
from cellctl.sim.image_truth import camera_pose_seeing_corner  # noqa: E402
from cellctl.sim.targets import Checkerboard, PlacedTarget  # noqa: E402
from cellctl.sim.world import sample_world  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m cellctl.bench.render", description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="frames to time (default 20)")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    cv2.setNumThreads(1)
    sim = SimConfig()
    intr = sim.camera.intrinsics
    rng = np.random.default_rng(args.seed)

    camera_model._CACHE.clear()
    t0 = time.perf_counter()
    renderer = CameraRenderer(intr, sim.camera.render)
    setup_s = time.perf_counter() - t0

    scenes = []
    for _ in range(args.runs):
        world = sample_world(sim.world, rng)
        corner = (rng.uniform(1300, 1700), rng.uniform(350, 750))
        R = rot_x(rng.normal(0, 0.01)) @ rot_y(rng.normal(0, 0.01)) @ rot_z(rng.normal(0, 0.02))
        scenes.append((world, camera_pose_seeing_corner(renderer.camera, world, corner, R_T_C=R)))
    it = iter(scenes * 3)

    def frame() -> None:
        world, pose = next(it)
        renderer.render(pose, world, rng=rng)

    frame()  # warm-up (page faults, first-call overheads)
    frame_s = median_s(frame, args.runs)
    # The same frames split into their two stages, timed frame by frame.
    shade_t, sensor_t = [], []
    for world, pose in scenes:
        t0 = time.perf_counter()
        signal, _ = renderer.render_signal(pose, world)
        t1 = time.perf_counter()
        renderer.expose(signal, rng)
        sensor_t.append(time.perf_counter() - t1)
        shade_t.append(t1 - t0)
    shade_s, sensor_s = statistics.median(shade_t), statistics.median(sensor_t)

    disturbed = CameraRenderer(
        intr,
        RenderConfig(
            disturbances=DisturbanceConfig(
                glare=GlareConfig(), occlusion=OcclusionConfig(), contrast_factor=0.5, defocus_sigma_px=1.0
            )
        ),
    )
    it_d = iter(scenes * 2)

    def disturbed_frame() -> None:
        world, pose = next(it_d)
        disturbed.render(pose, world, rng=rng)

    disturbed_s = median_s(disturbed_frame, args.runs)

    board = Checkerboard()
    placed = PlacedTarget(board, make_pose(rot_y(0.3) @ rot_x(-0.2), [-45.0, -25.0, 420.0]))
    board_runs = max(1, min(args.runs, 5))
    board_s = median_s(lambda: renderer.render(np.eye(4), None, targets=[placed], rng=rng), board_runs)

    image = renderer.render(scenes[0][1], scenes[0][0], rng=rng).image
    blur_s = median_s(lambda: cv2.GaussianBlur(image, (0, 0), 1.0), max(args.runs, 20))

    print(
        f"twin camera render, {intr.width_px} x {intr.height_px} 8-bit, one core, {args.runs} frames, seed {args.seed}"
    )
    print(f"  median frame (window corner, default noise)   {frame_s * 1e3:8.1f} ms")
    print(f"  split, medians: geometry + shading + lighting  {shade_s * 1e3:8.1f} ms")
    print(f"                  sensor (noise, 8-bit)          {sensor_s * 1e3:8.1f} ms")
    print(f"  median frame with all disturbances             {disturbed_s * 1e3:8.1f} ms")
    print(f"  median checkerboard frame ({board_runs} runs)         {board_s * 1e3:8.1f} ms")
    print(f"  baseline cv2.GaussianBlur (sigma 1, one frame) {blur_s * 1e3:8.1f} ms")
    print(f"  ratio frame / baseline                         {frame_s / blur_s:8.1f} x")
    print(f"  one-off: ray map + lighting field              {setup_s * 1e3:8.1f} ms (cached per intrinsics)")
    print(f"  ray map accuracy (worst re-distortion error)   {renderer.ray_map_residual_px:.1e} px")
    print(f"  target < 300 ms per frame: {'met' if frame_s < 0.3 else 'NOT met'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
