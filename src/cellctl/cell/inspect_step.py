"""The inspect step: the cell measures the glass it has just installed (issue 16).

After the install the gripper releases the glass and the flange backs away from the wall, then
goes to the shooting pose of the corrected workpiece frame T2. There the camera measures the
gaps between the glass's edges and the opening's edges at the corner (in-plane dX, dY, dRz), and
the laser reads the glass and the wall at each flush spot of the recipe (dZ, dRx, dRy). Both are
measured against the opening itself: the gaps are differences within one image, the flush is a
difference of neighbouring laser points, so the robot's and the mountings' calibration errors
cancel instead of entering the result.
"""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING, Any

import numpy as np

from cellctl.align import AlignmentError, plan_spot_poses
from cellctl.align.laser_points import laser_points
from cellctl.cell.cycle_failure import CycleFailed
from cellctl.cell.inspect_figures import inspection_image, record_measured
from cellctl.cell.inspect_arc import inspect_arc_corner
from cellctl.cell.sweep import sweep_flush
from cellctl.compensate import shooting_pose_in
from cellctl.domain import AlarmCode, CycleStep
from cellctl.geometry.pose import Pose, apply_pose, invert_pose, make_pose
from cellctl.inspection import (
    FlushError,
    FlushResult,
    MeasuredDeviation,
    fit_flush,
)
from cellctl.inspection.flush import on_layout
from cellctl.ports import DeviceError, LaserStatus
from cellctl.vision.annotate_gap import annotate_gaps
from cellctl.vision.gap import GapMeasurement, measure_gaps
from cellctl.vision.gap_figures import in_plane_from_gaps

if TYPE_CHECKING:
    from cellctl.cell.cycle import CycleRun

STEP = CycleStep.INSPECT


def _failed(reason: str) -> CycleFailed:
    return CycleFailed(STEP, AlarmCode.INSPECTION_FAILED, reason)


async def release_and_back_off(run: CycleRun, T2: Pose, reached: Pose) -> None:
    """Open the gripper at the install pose, then back the flange out along the wall's normal."""
    cfg = run.process.inspect
    try:
        await run.dev.robot.set_gripper(False, timeout_s=run.motion.read_timeout_s)
    except DeviceError as err:
        raise CycleFailed(STEP, AlarmCode.ROBOT_FAULT, f"the gripper did not release the glass: {err}") from err
    run.glass_on_gripper = False  # from here on the moves run at the empty gripper's speeds
    # T2's z axis points into the wall: back off along -z of T2, keeping the flange's orientation.
    out = T2 @ make_pose(np.eye(3), [0.0, 0.0, -cfg.back_off_mm]) @ invert_pose(T2) @ reached
    await run.move(STEP, out, speed_mm_s=run.motion.back_off_mm_s())


async def measure_gaps_at_shooting_pose(run: CycleRun, T2: Pose) -> tuple[np.ndarray, GapMeasurement]:
    """Go to the shooting pose of T2, grab, and find the opening's and the glass's edges: the image and them."""
    cal = run.cal
    image = await inspection_image(run, T2)
    gap_px = run.process.inspect.nominal_gap_mm / cal.nine_point.mm_per_px
    m = await asyncio.to_thread(
        measure_gaps, image, cal.lens, cal.template, run.vision.gap, gap_px_expected=gap_px, feature=run.vision.feature,
        opening_polarity=run.vision.opening_polarity, taught=cal.taught_profile,
    )
    if not m.ok:
        await record_inspection_image(run, image, m, None)
        raise _failed(f"the gaps could not be measured: {m.message}")
    return image, m


async def record_inspection_image(
    run: CycleRun, image: np.ndarray, m: GapMeasurement, figures: dict[str, float] | None
) -> None:
    """The inspection image with its edges (and the figures, or the refusal) as the cycle's ``inspect`` image."""
    png = await asyncio.to_thread(annotate_gaps, image, m, run.cal.lens, figures=figures)
    await run.rec.image("inspect", png)


async def _read_spot(run: CycleRun, index: int, what: str) -> float | None:
    """Up to ``reads_per_spot`` readings at a standing pose; the first with a distance counts."""
    for _ in range(run.process.inspect.reads_per_spot):
        try:
            reading = await run.dev.laser.read(timeout_s=run.motion.read_timeout_s)
        except DeviceError as err:
            raise CycleFailed(STEP, AlarmCode.LASER_READ_FAILED, f"flush reading at {what} spot {index} failed: {err}") from err
        if reading.status is LaserStatus.OK and reading.distance_mm is not None:
            return float(reading.distance_mm)
    return None


async def measure_flush(run: CycleRun, T2: Pose) -> tuple[FlushResult, dict[str, Any]]:
    """Laser readings on the glass and the wall at each flush spot (or along the sweep, where the
    alignment swept); their planes against each other, and the step's figures of them."""
    if run.sweep_latency_s is not None:
        flush, sweep = await sweep_flush(run, T2)
        return flush, {"flush_sweep": sweep, "flush_mm_range": [min(flush.flush_mm), max(flush.flush_mm)]}
    cfg, cal = run.process.inspect, run.cal
    R_flange = shooting_pose_in(cal.taught, T2)[:3, :3]  # the camera parallel to the wall, as when shooting
    xy = np.array([p for s in cfg.flush_spots for p in (s.glass_mm, s.wall_mm)], dtype=float)
    standoff = run.process.align.laser_standoff_mm
    planned = plan_spot_poses(T2, xy, R_flange, cal.laser_r, cal.laser_l, standoff)
    rows: list[dict[str, Any]] = []
    glass_pts: list[np.ndarray] = []
    wall_pts: list[np.ndarray] = []
    for k, spot in enumerate(cfg.flush_spots):
        found: list[tuple[Pose, float]] = []
        for j, what in ((0, "glass"), (1, "wall")):
            reached = await run.move(STEP, planned[2 * k + j])
            d = await _read_spot(run, k, what)
            if d is not None:
                found.append((reached, d))
        row: dict[str, Any] = {"index": k, "glass_mm": list(spot.glass_mm), "wall_mm": list(spot.wall_mm)}
        if len(found) == 2:
            try:
                pts = laser_points(np.stack([p for p, _ in found]), cal.laser_r, cal.laser_l, [d for _, d in found], cal.laser_range_mm)
            except AlignmentError as err:
                row["missing"] = str(err)
            else:
                g, w = apply_pose(invert_pose(T2), pts)
                glass_pts.append(g)
                wall_pts.append(w)
                row["step_mm"] = float(g[2] - w[2])
        else:
            row["missing"] = "no distance from the glass or the wall"
        rows.append(row)
    missing = [r["index"] for r in rows if "missing" in r]
    if len(glass_pts) < cfg.min_flush_spots:
        raise _failed(
            f"only {len(glass_pts)} of {len(cfg.flush_spots)} flush spots gave both readings (missing {missing}; "
            f"at least {cfg.min_flush_spots} needed): is the glass in the opening, are the spots on glass and wall?"
        )
    used = [r["index"] for r in rows if "missing" not in r]
    try:
        flush = fit_flush(
            np.stack(glass_pts), np.stack(wall_pts), max_rms_mm=cfg.max_flush_rms_mm, outlier_mm=cfg.flush_outlier_mm,
            min_spots=cfg.min_flush_spots, spots=used,
        )  # fmt: skip
    except FlushError as err:
        raise _failed(str(err)) from err
    flush = on_layout(flush, used, [s.glass_mm for s in cfg.flush_spots])
    return flush, {"flush_spots": rows, "flush_mm": list(flush.flush_mm)} | spot_check_figures(flush)


def spot_check_figures(flush: FlushResult) -> dict[str, Any]:
    """The spots left out, those the others cannot check, and why the result may not feed the quality loop."""
    out: dict[str, Any] = {
        "flush_rejected": [{"index": r.index, "surface": r.surface, "off_mm": round(r.off_mm, 4),
                            "limit_mm": round(r.limit_mm, 4)} for r in flush.rejected],
        "flush_unverifiable": [{"index": u.index, "detects_above_mm": None if u.detects_above_mm is None
                                else round(u.detects_above_mm, 3)} for u in flush.unverifiable],
    }  # fmt: skip
    if flush.unreliable is not None:
        out["flush_unreliable"] = flush.unreliable
    return out


async def inspect_install(run: CycleRun, T2: Pose, reached: Pose) -> MeasuredDeviation:
    """Release, back off, measure the gaps and the flush: the installed glass's six figures."""
    await run.rec.step_started(STEP)
    await release_and_back_off(run, T2, reached)
    if run.feature.arc is not None:  # a large corner radius: the gaps on the arc
        return await inspect_arc_corner(run, T2, measure_flush)
    image, gaps = await measure_gaps_at_shooting_pose(run, T2)
    try:
        flush, flush_figures = await measure_flush(run, T2)
    except CycleFailed:
        await record_inspection_image(run, image, gaps, None)  # the edges were found; show them beside the flush's failure
        raise
    cal = run.cal
    plane = in_plane_from_gaps(
        gaps,
        cal.nine_point,
        nominal_gap_mm=run.process.inspect.nominal_gap_mm,
        dz_mm=flush.dz_mm,
        working_distance_mm=run.process.working_distance_mm,
        principal_point_px=(cal.lens.cx, cal.lens.cy),
    )
    await record_inspection_image(
        run, image, gaps, {"top_gap_mm": plane.top_gap_mm, "right_gap_mm": plane.right_gap_mm, "dx_mm": plane.dx_mm,
              "dy_mm": plane.dy_mm, "drz_rad": plane.drz_rad},
    )  # fmt: skip
    return await record_measured(run, plane, flush, flush_figures)
