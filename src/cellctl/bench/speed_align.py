"""``cellctl bench speed``, alignment: ``compute_alignment`` (paper section 3) against a bare plane fit.

Median time on laser spots measured in the twin at several car-body postures, and its ratio to
an SVD of the centred points.
"""

from __future__ import annotations

import statistics
import time
from typing import Any

import numpy as np

from cellctl.bench.progress import Progress
from cellctl.bench.sources import BenchSettingsError
from cellctl.bench.stats import percentile
from cellctl.config import CellConfig


def measure_alignment(config: CellConfig, calls: int, seed: int, progress: Progress | None = None) -> dict[str, Any]:
    """Median ``compute_alignment`` on spots measured in the twin at several car-body postures."""
    from cellctl.align import compute_alignment, plan_spot_poses
    from cellctl.ports import LaserStatus
    from cellctl.sim.alignment_run import shooting_orientation
    from cellctl.sim.cell import SimCell
    from cellctl.sim.world import nominal_world

    cell = SimCell(config.sim, seed=seed)
    laser, align = config.sim.laser, config.process.align
    T_H_C = config.sim.camera.hand_eye.T_H_C()
    T0 = nominal_world(config.sim.world).T_B_T
    planned = plan_spot_poses(T0, align.spots_mm, shooting_orientation(config), laser.r, laser.l, align.laser_standoff_mm)
    inputs = []
    for _ in range(10):
        cell.new_car_body()
        poses, dist = [], []
        for X in planned:
            cell.execute(X)
            status, d = cell.laser_reading()
            if status is LaserStatus.OK and d is not None:
                poses.append(cell.belief_flange_pose())
                dist.append(d)
        if len(dist) >= 3:
            inputs.append((np.stack(poses), np.array(dist)))
    if not inputs:
        raise BenchSettingsError("no car-body posture gave three laser spots; check process.align.spots_mm")
    kw = dict(
        range_mm=(laser.range_min_mm, laser.range_max_mm), inlier_threshold_mm=align.inlier_threshold_mm,
        max_rms_mm=align.max_rms_mm, min_collinearity=align.min_collinearity, T_B_H_current=planned[-1],
    )  # fmt: skip
    wd = config.process.working_distance_mm
    compute_alignment(inputs[0][0], inputs[0][1], laser.r, laser.l, T_H_C, wd, **kw)  # warm-up
    align_t, svd_t = [], []
    for k in range(calls):
        poses, dist = inputs[k % len(inputs)]
        t0 = time.perf_counter()
        res = compute_alignment(poses, dist, laser.r, laser.l, T_H_C, wd, **kw)
        align_t.append(time.perf_counter() - t0)
        pts = res.points_B
        t0 = time.perf_counter()
        np.linalg.svd(pts - pts.mean(axis=0))
        svd_t.append(time.perf_counter() - t0)
        if progress is not None:
            progress.advance()
    a, s = statistics.median(align_t), statistics.median(svd_t)
    return {
        "calls": calls,
        "spots": len(planned),
        "align_median_s": a,
        "align_p90_s": percentile(align_t, 90),
        "svd_median_s": s,
        "ratio_to_svd": a / s,
    }
