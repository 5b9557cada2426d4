"""``cellctl bench speed``, vision: the window-corner detector (paper 4.2) against ``cv2.Canny``.

Median detection time per 2048 x 2048 shooting view rendered by the twin (the scenes of
:mod:`cellctl.bench.vision`), on one core, and its ratio to ``cv2.Canny`` alone on the same frames.
"""

from __future__ import annotations

import statistics
import time
from typing import Any

import cv2
import numpy as np

from cellctl.bench.progress import Progress
from cellctl.bench.stats import percentile
from cellctl.config import CellConfig


def measure_vision(config: CellConfig, frames: int, seed: int, progress: Progress | None = None) -> dict[str, Any]:
    """Median corner detection per frame over distinct shooting views, and cv2.Canny on the same frames."""
    from cellctl.bench.vision import shooting_scene
    from cellctl.sim.camera import CameraRenderer
    from cellctl.vision import Lens, detect_corner

    sim = config.sim
    renderer = CameraRenderer(sim.camera.intrinsics, sim.camera.render)
    lens = Lens.from_intrinsics(sim.camera.intrinsics)
    rng = np.random.default_rng(seed)
    distinct = min(frames, 8)
    images = []
    for _ in range(distinct):
        world, pose = shooting_scene(renderer, sim, rng)
        images.append(renderer.render(pose, world, rng=rng).image)
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        detect_corner(images[0], lens, config.vision)  # warm-up
        detect_t, canny_t, refused = [], [], 0
        c = config.vision.coarse
        for k in range(frames):
            img = images[k % distinct]
            t0 = time.perf_counter()
            m = detect_corner(img, lens, config.vision)
            detect_t.append(time.perf_counter() - t0)
            refused += not m.ok
            t0 = time.perf_counter()
            cv2.Canny(img, c.canny_low, c.canny_high, L2gradient=c.canny_l2_gradient)
            canny_t.append(time.perf_counter() - t0)
            if progress is not None:
                progress.advance()
    finally:
        cv2.setNumThreads(threads)
    d, cn = statistics.median(detect_t), statistics.median(canny_t)
    return {
        "frames": frames,
        "distinct_frames": distinct,
        "size_px": list(images[0].shape[::-1]),
        "detect_median_s": d,
        "detect_p90_s": percentile(detect_t, 90),
        "canny_median_s": cn,
        "ratio_to_canny": d / cn,
        "refused": refused,
        "threads": 1,
    }
