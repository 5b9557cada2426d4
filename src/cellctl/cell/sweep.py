"""Reading the wall on the move (issue 19): the laser stores readings while the flange sweeps a path.

At the path's first corner the flange moves along the beam (in, out and in when the sweep times
the laser; in once when it checks the latency kept from an earlier timing, :mod:`cellctl.cell.laser_timing`),
then follows the path at the sweep speed; meanwhile the laser stores a reading every storage cycle
and the robot streams its pose (supervised: a stale stream stops the robot). The moves along the
beam, where the distance changes with the motion, time the laser against the feedback; every
reading is then paired with the flange pose at its instant and the plane is fitted to an even
selection of those along the legs.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from cellctl.align import AlignmentError, plan_spot_poses
from cellctl.align.beam_timing import estimate_latency_at_spot
from cellctl.align.laser_points import laser_points, sweep_route
from cellctl.align.onthefly import (
    MIN_READINGS,
    LatencyAtEdge,
    LatencyEstimate,
    TimingReadings,
    at_corners,
    even_along_path,
    pair_stored_readings,
    pose_samples_arrays,
    standing,
    stored_instants,
)
from cellctl.cell.cycle_failure import CycleFailed
from cellctl.cell.feedback_gap import gap_side, stream_figures, stream_stats
from cellctl.cell.robots import pose_stream_of
from cellctl.cell.sweep_start import StartWindow, SweepLatency, start_known
from cellctl.compensate import shooting_pose_in
from cellctl.domain import AlarmCode, CycleStep
from cellctl.geometry.pose import Pose, apply_pose, invert_pose
from cellctl.inspection import FlushError, FlushResult
from cellctl.inspection.flush_crossing import flush_from_sweep, surface_at
from cellctl.ports import DeviceError, PoseStream, StoringSensor

if TYPE_CHECKING:
    from cellctl.cell.cycle import CycleRun

log = logging.getLogger(__name__)
STEP = CycleStep.ALIGN
SUPERVISION_PERIOD_S = 0.002  # how often the feedback's freshness is checked while the robot sweeps (host seconds)
AT_CORNER_MM = 2.0  # a reading at rest this near a corner's commanded position was read standing at that corner
CHECK_WINDOW_S = 0.005  # a check of the kept latency searches this far either side of it before the whole range


def sweep_unavailable(run: CycleRun) -> str | None:
    """Why this cell cannot read the wall on the move (its laser cannot store, or its robot streams no pose), or None."""
    if not isinstance(run.dev.laser, StoringSensor):
        return "the laser driver cannot store readings"
    stream = pose_stream_of(run.dev.robot)
    if stream is None:
        return "the robot driver streams no position feedback"
    if (why := stream.stream_unavailable()) is not None:
        return f"the robot driver streams no position feedback: {why}"
    return None


@dataclass(frozen=True)
class Swept:
    """The readings of one sweep along its legs, each with its flange pose, and how they were taken."""

    poses: np.ndarray  # (K, 4, 4) T_B_H at each reading's instant minus the latency
    distances: np.ndarray  # (K,) mm along l from r
    latency_s: float
    figures: dict[str, Any]
    estimate: LatencyEstimate | None = None  # the sweep's own estimate, where it timed or checked the laser
    rest_poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))  # readings with the flange standing
    rest_distances: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rest_stops: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))  # (M,) the corner each was read at
    legs: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))  # (K,) leg j runs corners[j] -> corners[j + 1]
    moving: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # (K,) the flange moved (not settling at a corner)
    start: StartWindow | None = None  # the laser storage's start window (None: its driver gives none)


async def sweep_readings(
    run: CycleRun,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The alignment's sweep: the legs' flange poses (N, 4, 4), distances (N,), the figures, and the
    poses, distances and stops of the readings taken with the flange standing (at the path's corners).

    The sweep times the laser, checks the kept latency, or (``fixed_latency_s``) takes the configured one.
    """
    cfg, cal, kept = run.process.align.sweep, run.cal, run.laser_timing
    corners = plan_spot_poses(
        cal.taught.T0, cfg.path_mm, cal.taught.C_Pos_0[:3, :3], cal.laser_r, cal.laser_l, run.process.align.laser_standoff_mm
    )
    laser, robot = run.dev.laser, run.dev.robot
    how: Literal["timed", "checked", "fixed"] = "checked"
    if cfg.fixed_latency_s is not None:
        swept = await sweep_path(run, STEP, corners, latency_s=cfg.fixed_latency_s, stops=True)
        timing: dict[str, Any] = {"latency": "fixed (process.align.sweep.fixed_latency_s)"}
        how = "fixed"
    elif (why := kept.why_time(laser, robot, cfg.retime_every)) is not None:
        swept = await sweep_path(run, STEP, corners, latency_s=None, stops=True)
        assert swept.estimate is not None
        kept.timed(swept.estimate, laser, robot, swept.start)
        timing, how = {"latency": "timed", "timed_because": why}, "timed"
    else:
        assert kept.latency_s is not None
        timing = {"latency": "checked"}

        def check(estimate: LatencyEstimate, start: StartWindow | None) -> float:
            used_s, timing["latency_check"] = kept.checked(estimate, cfg.latency_check_tolerance_s, start)
            return used_s

        swept = await sweep_path(run, STEP, corners, latency_s=None, check=lambda start: kept.kept_at(start)[0], choose=check, stops=True)
    run.sweep_latency_s = swept.latency_s
    own = swept.estimate  # the flush sweep takes this sweep's own latency, not the kept one it may have paired with
    kept.last_sweep = SweepLatency(
        swept.latency_s if own is None else own.latency_s, None if own is None else own.sigma_s, how, swept.start, swept.latency_s
    )  # fmt: skip
    keep = even_along_path(swept.poses, cfg.max_points)
    figures = swept.figures | timing | {"readings_fitted": int(len(keep))}
    return swept.poses[keep], swept.distances[keep], figures, (swept.rest_poses, swept.rest_distances, swept.rest_stops)


async def sweep_flush(run: CycleRun, T2: Pose) -> tuple[FlushResult, dict[str, Any]]:
    """The flush on the move: sweep the inspection's path past the installed glass, with the alignment sweep's own
    latency moved to this sweep's storage start (:mod:`cellctl.cell.sweep_start`; refused beyond the tolerance).

    Each reading's laser point is taken into T2 and sorted by where it falls: on the glass (inside
    the glass's edge) or on the wall (outside the opening's, past its far sides too: the outline of the
    recipe's own opening, ``run.process.opening``), none within the margin of an edge. The
    legs whose planned ends lie on different surfaces cross an edge; the step at each crossing comes
    from that leg's readings alone (:mod:`cellctl.inspection.flush_crossing`).
    """
    cal, insp = run.cal, run.process.inspect
    reference = run.laser_timing.last_sweep
    assert run.sweep_latency_s is not None and reference is not None, "the alignment's sweep times the laser first"
    assert reference.paired_s == run.sweep_latency_s, "the latency kept is this cycle's alignment sweep's"
    R_flange = shooting_pose_in(cal.taught, T2)[:3, :3]  # the camera parallel to the wall, as when shooting
    corners = plan_spot_poses(T2, insp.sweep_path_mm, R_flange, cal.laser_r, cal.laser_l, run.process.align.laser_standoff_mm)
    swept = await sweep_path(run, CycleStep.INSPECT, corners, latency_s=None, moved_from=reference)
    lo, hi = cal.laser_range_mm
    inside = (swept.distances >= lo) & (swept.distances <= hi)  # beyond the range (through the gap, say): left out, counted
    try:
        pts = apply_pose(
            invert_pose(T2), laser_points(swept.poses[inside], cal.laser_r, cal.laser_l, swept.distances[inside], cal.laser_range_mm)
        )  # fmt: skip
    except AlignmentError as err:
        raise CycleFailed(CycleStep.INSPECT, AlarmCode.INSPECTION_FAILED, f"the flush sweep's readings gave no points: {err}") from err
    legs = np.where(swept.moving[inside], swept.legs[inside], -1)
    try:
        flush, crossings, missing = await asyncio.to_thread(  # the settle at a leg's end is not mirrored at its start: left out
            flush_from_sweep, pts, legs, insp.sweep_path_mm, opening=run.process.opening,
            gap_mm=insp.nominal_gap_mm, margin_mm=insp.sweep_margin_mm, max_rms_mm=insp.max_flush_rms_mm,
        )  # fmt: skip
    except FlushError as err:
        raise CycleFailed(CycleStep.INSPECT, AlarmCode.INSPECTION_FAILED, str(err)) from err
    surface = surface_at(pts[:, :2], insp.nominal_gap_mm, insp.sweep_margin_mm, run.process.opening)
    rows = [{"at_mm": [round(c.x_mm, 1), round(c.y_mm, 1)], "step_mm": c.step_mm, "glass_readings": c.glass_readings,
             "wall_readings": c.wall_readings} for c in crossings]  # fmt: skip
    figures = swept.figures | {"readings_out_of_range": int(np.count_nonzero(~inside)),
                               "glass_readings": int(np.count_nonzero(surface > 0)), "wall_readings": int(np.count_nonzero(surface < 0)),
                               "crossings": rows} | ({"crossings_missing": missing} if missing else {})  # fmt: skip
    return flush, figures


async def sweep_path(
    run: CycleRun, step: CycleStep, corners: list[Pose], *, latency_s: float | None,
    check: Callable[[StartWindow | None], float] | None = None,
    choose: Callable[[LatencyEstimate, StartWindow | None], float] | None = None, stops: bool = False,
    moved_from: SweepLatency | None = None,
) -> Swept:
    """Sweep the flange through ``corners`` while the laser stores and the robot streams; pair the legs' readings.

    With ``latency_s`` given, the sweep follows the corners and pairs with it. Else it moves along
    the beam at the first corner and estimates the latency from that: in, out and in (timing), or
    with ``check`` (the kept latency at this sweep's storage start window) in once, searching near it;
    ``choose`` then turns the estimate and this sweep's storage start window into the latency the readings
    are paired with (default: the estimate's). With ``stops`` the readings taken with the flange standing
    are kept too (the alignment's distance comes from them).
    With ``moved_from`` (an earlier sweep's own latency) the sweep follows the corners and pairs with that
    latency moved to this storage's start; refused (before the robot moves) when it cannot be known within
    the latency check's tolerance. Each sweep starts its storage again while its start is not known within that.
    """
    cfg, cal = run.process.align.sweep, run.cal
    laser, stream = run.dev.laser, pose_stream_of(run.dev.robot)
    assert isinstance(laser, StoringSensor) and stream is not None, "sweep_unavailable() first"
    beam_moves = 0 if latency_s is not None or moved_from is not None else 1 if check is not None else 3
    route = sweep_route(corners, cal.laser_l, cfg.approach_mm, beam_moves=beam_moves)
    timing = route[1 : 1 + beam_moves]
    await run.move(step, route[0], kind="joint")
    timeout = run.motion.read_timeout_s
    speed = run.process.sweep_speed_mm_s(glass_on_gripper=run.glass_on_gripper)
    path_s = _path_seconds(corners, speed) + beam_moves * cfg.approach_mm / speed
    count = int(min(65535, np.ceil(3.0 * path_s / cfg.storage_cycle_s) + 100))
    approach: list[float] = []
    leg_starts: list[float] = []

    async def path() -> None:
        # In, out and in again along the beam: the latency shifts the readings one way going in and the
        # other going out, while what depends on where the flange is (the robot's accuracy along the way,
        # the laser's linearity) is the same both ways, so it does not pass for latency. A check moves in once.
        approach.append(run.dev.clock())
        for T in timing:
            await run.move(step, T, speed_mm_s=speed)
        approach.append(run.dev.clock())
        for T in route[1 + len(timing):]:  # leg j: corners[j] -> corners[j + 1]
            leg_starts.append(run.dev.clock())
            await run.move(step, T, speed_mm_s=speed)

    try:
        await stream.start_stream(timeout_s=timeout)
        tolerance = cfg.latency_check_tolerance_s
        start = await start_known(laser, cycle_s=cfg.storage_cycle_s, count=count, timeout_s=timeout, within_s=tolerance)
        if moved_from is not None:
            latency_s, moved = _moved_latency(step, moved_from, start, tolerance)
        await _supervised(run, step, path(), stream)
        stored = await laser.stop_storage(timeout_s=timeout + path_s)  # the read-out is on the serial line: up to as long as the path
        samples = await stream.stop_stream(timeout_s=timeout)
    except BaseException as err:  # failed, or cancelled (the operator's Stop): leave nothing running
        await asyncio.shield(_leave_nothing_running(stream, laser, timeout, path_s))
        if isinstance(err, DeviceError):
            raise CycleFailed(step, AlarmCode.LASER_READ_FAILED, f"reading the wall on the move failed: {err}") from err
        raise
    window = (approach[0], approach[1])
    instants, distances = stored_instants(stored)
    t, T = await asyncio.to_thread(pose_samples_arrays, samples)  # thousands of matrices: off the loop
    latency: LatencyEstimate | None = None
    if latency_s is None:  # plane fits: off the loop
        check_s = None if check is None else check(start)  # near the kept latency moved to this start
        latency = await asyncio.to_thread(_latency, run, step, instants, distances, (t, T), window, check_s)
        lat_s = latency.latency_s if choose is None else choose(latency, start)
    else:
        lat_s = float(latency_s)
    try:
        paired = await asyncio.to_thread(pair_stored_readings, stored, samples, lat_s, max_gap_s=cfg.max_feedback_gap_s)
    except ValueError as err:
        raise CycleFailed(step, _failed_code(step), f"readings could not be paired with the robot's poses: {err}") from err
    on_path = np.flatnonzero(paired.instants > window[1])  # the moves along the beam only time the laser
    wanted = int(np.count_nonzero((instants > window[1]) & np.isfinite(distances)))
    if len(on_path) < cfg.min_paired_share * wanted:
        stats = stream_stats(stream)
        await _step_figures(run, step, stream_figures(stats))
        raise CycleFailed(
            step, AlarmCode.POSITION_FEEDBACK_LOST,
            f"only {len(on_path)} of the {wanted} readings along the path had a robot pose within "
            f"{1e3 * cfg.max_feedback_gap_s:g} ms (the position feedback had gaps): nothing is fitted to guesses; "
            f"{gap_side(stats, cfg.max_feedback_gap_s, came_after=1)}",
        )  # fmt: skip
    figures: dict[str, Any] = {
        "mode": "on_the_fly",
        "stored_readings": len(stored.distances_mm),
        "readings_with_distance": int(sum(d is not None for d in stored.distances_mm)),
        "paired_readings": len(paired.distances),
        "readings_on_the_legs": int(len(on_path)),
        "feedback_samples": len(samples),
        "latency_ms": 1e3 * lat_s,
        "speed_mm_s": speed,
        "storage_start": None if start is None else start.figures(),
    }
    if moved_from is not None:
        figures |= moved
    if latency is not None:
        figures |= {"latency_sigma_ms": 1e3 * latency.sigma_s, "approach_rms_mm": latency.rms_mm}
    # Each reading's leg: the moves end at fine points (the next starts after this one's settle), so a reading
    # belongs to the last move started before its pose's instant, leg j - 1, and standing it is at corner j.
    stop_of = np.searchsorted(leg_starts, paired.instants - lat_s, side="right")
    at_rest = await asyncio.to_thread(standing, t, T, paired.instants - lat_s)  # once for every paired reading
    legs = np.maximum(stop_of[on_path] - 1, 0)
    swept = Swept(
        paired.poses[on_path], paired.distances[on_path], lat_s, figures, latency, legs=legs, moving=~at_rest[on_path], start=start
    )  # fmt: skip
    if not stops:
        return swept
    rest, corner_of = at_corners(paired.poses, at_rest, corners, AT_CORNER_MM, stop_of=stop_of)
    figures["readings_at_rest"] = int(len(rest))
    figures["readings_at_rest_per_corner"] = np.bincount(corner_of, minlength=len(corners)).tolist()  # each weighs the same
    return replace(swept, rest_poses=paired.poses[rest], rest_distances=paired.distances[rest], rest_stops=corner_of)


async def _supervised(run: CycleRun, step: CycleStep, moves: Coroutine[Any, Any, None], stream: PoseStream) -> None:
    """Run the moves while the robot's feedback stays fresh; on a stale feedback stop the robot and fail (alarm 1402)."""
    cfg = run.process.align.sweep
    since = run.dev.clock()  # the stream has just started: its first sample may still be on its way
    task = asyncio.ensure_future(moves)
    try:
        while True:
            done, _ = await asyncio.wait({task}, timeout=SUPERVISION_PERIOD_S)
            if done:
                return task.result()
            now = run.dev.clock()  # before the sample: a host stall between the two must not read as a stale stream
            latest = stream.latest()
            age = now - (since if latest is None else latest.t_s)
            if age > cfg.feedback_stale_s:
                at_trip = stream_stats(stream)  # what came before the gap was found (samples after it tell its side)
                break
    finally:
        if not task.done():
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
    try:
        await run.dev.robot.stop(timeout_s=run.motion.read_timeout_s)
    except DeviceError as err:
        raise CycleFailed(step, AlarmCode.ROBOT_FAULT, f"the position feedback stopped and the robot did not stop: {err}") from err
    why = await _stream_fault(stream, run.motion.read_timeout_s)
    stats = stream_stats(stream)
    came_after = 1 if at_trip is None or stats is None else stats.received - at_trip.received
    await _step_figures(run, step, stream_figures(stats))
    raise CycleFailed(
        step, AlarmCode.POSITION_FEEDBACK_LOST,
        f"the robot's position feedback stopped mid-path (no sample for {age:.3f} s, limit {cfg.feedback_stale_s:g} s{why}): "
        f"the robot was stopped and nothing was fitted; {gap_side(stats, age, came_after=came_after)}",
    )  # fmt: skip


async def _stream_fault(stream: PoseStream, timeout_s: float) -> str:
    """Why the stream ended, as its stop refuses it (a stepped controller clock, a lost link); '' when it stops cleanly."""
    try:
        await stream.stop_stream(timeout_s=timeout_s)
    except DeviceError as err:
        return f"; {err}"
    return ""


async def _step_figures(run: CycleRun, step: CycleStep, figures: dict[str, Any]) -> None:
    """Add ``figures`` to the failing step's record (best effort: the failure is what the cycle reports)."""
    if figures:
        with contextlib.suppress(RuntimeError):
            await run.rec.step_figures(step, figures)


async def _leave_nothing_running(stream: PoseStream, laser: StoringSensor, timeout_s: float, path_s: float) -> None:
    """After a sweep cut short: no stream (EGM guidance waits for its end), no laser storing (its read-out: what it
    stored so far). Best effort: a device that fails here has already failed the sweep."""
    stops: tuple[Callable[[], Coroutine[Any, Any, object]], ...] = (
        lambda: stream.stop_stream(timeout_s=timeout_s), lambda: laser.stop_storage(timeout_s=timeout_s + path_s),
    )
    for stop in stops:
        try:
            await stop()
        except DeviceError as err:
            log.info("after the sweep: %s", err)


def _moved_latency(step: CycleStep, ref: SweepLatency, start: StartWindow | None, tolerance_s: float) -> tuple[float, dict[str, Any]]:
    """The latency (s) this sweep pairs with, moved from ``ref``'s storage start to ``start``, and the record's figures
    of where it came from; CycleFailed when it may be off by more than ``tolerance_s`` (s)."""
    latency_s, bound_s = ref.moved_to(start)
    if bound_s > tolerance_s:
        here = "not given" if start is None else f"{1e3 * start.width_s:.2f} ms (after {start.restarts} restarts)"
        there = "not given" if ref.start is None else f"{1e3 * ref.start.width_s:.2f} ms"
        raise CycleFailed(
            step, _failed_code(step),
            f"this sweep's readings cannot be paired within {1e3 * tolerance_s:g} ms of the robot's poses: the laser's "
            f"storage start is known within {here} here and {there} in the alignment's sweep (the cell PC noticed the "
            f"laser's AS echo late: a loaded PC), so the alignment's latency may be {1e3 * bound_s:.2f} ms off; nothing "
            "was measured on the move (process.align.sweep.latency_check_tolerance_s)",
        )  # fmt: skip
    figures = {
        "latency": f"the alignment sweep's ({ref.how}), moved to this sweep's storage start; not checked by this sweep",
        "latency_source": {"sweep": "align", "how": ref.how, "latency_ms": 1e3 * ref.latency_s,
                           "sigma_ms": None if ref.sigma_s is None else 1e3 * ref.sigma_s, "paired_ms": 1e3 * ref.paired_s,
                           "storage_start": None if ref.start is None else ref.start.figures()},
        "latency_moved_ms": 1e3 * (latency_s - ref.latency_s), "latency_bound_ms": 1e3 * bound_s, "latency_checked": False,
    }  # fmt: skip
    return latency_s, figures


def _failed_code(step: CycleStep) -> AlarmCode:
    """The alarm of a sweep that cannot give its figures: the alignment's, or the inspection's."""
    return AlarmCode.ALIGNMENT_FAILED if step is CycleStep.ALIGN else AlarmCode.INSPECTION_FAILED


def _path_seconds(corners: list[Pose], speed_mm_s: float) -> float:
    return float(sum(np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in zip(corners, corners[1:]))) / speed_mm_s


def _latency(
    run: CycleRun, step: CycleStep, instants: np.ndarray, distances: np.ndarray, feedback: tuple[np.ndarray, np.ndarray],
    approach: tuple[float, float], check_s: float | None,
) -> LatencyEstimate:
    """The latency between the laser's and the robot's clocks, from the readings of the approach along the beam.

    There the distance changes with the motion while the spot stays on one wall point, so the latency is
    the one that puts the points on one point (:mod:`cellctl.align.beam_timing`); over the legs the robot's
    error, drawn anew at each stop, could pass for latency. A check searches within ``CHECK_WINDOW_S`` of the kept
    latency ``check_s`` first (a fraction of the grid), then the whole range.
    """
    cfg, cal = run.process.align.sweep, run.cal
    t, T = feedback
    during = (instants >= approach[0]) & (instants <= approach[1])
    in_approach = int(np.count_nonzero(during & np.isfinite(distances)))
    if t.size >= 2 and in_approach == 0:
        x, y = cfg.path_mm[0]
        raise CycleFailed(
            step, AlarmCode.ALIGNMENT_FAILED,
            f"the approach along the beam at the sweep's first corner ({x:g}, {y:g}) mm in T0 gave no laser reading at all, "
            "so the laser could not be timed against the robot: the beam there may go through the window opening (this car "
            "body stands further off its taught place than that corner's distance from the opening allows), or no wall is in "
            "the laser's range. Move the first corner of process.align.sweep.path_mm (where the laser is timed) further from "
            "the opening than the car body's placement varies and teach again; is the car body in position?",
        )  # fmt: skip
    if t.size < 2 or in_approach < MIN_READINGS:
        raise CycleFailed(
            step, AlarmCode.ALIGNMENT_FAILED,
            f"the approach gave {in_approach} laser readings (at least {MIN_READINGS} needed) and the sweep {t.size} robot "
            "poses: too few to time the laser against the robot (is the wall in the laser's range at the path's first "
            "corner? a longer process.align.sweep.approach_mm or a shorter storage_cycle_s gives more)",
        )  # fmt: skip
    def estimate(window: tuple[float, float]) -> LatencyEstimate:
        return estimate_latency_at_spot(TimingReadings.checked(instants[during], distances[during], t, T, cal.laser_r, cal.laser_l, window))

    try:
        est: LatencyEstimate | None = None
        if check_s is not None:
            with contextlib.suppress(LatencyAtEdge):
                est = estimate((check_s - CHECK_WINDOW_S, check_s + CHECK_WINDOW_S))
        if est is None:
            est = estimate(cfg.latency_search_s)
    except ValueError as err:
        raise CycleFailed(step, AlarmCode.ALIGNMENT_FAILED, f"the laser could not be timed against the robot: {err}") from err
    if est.sigma_s > cfg.max_latency_sigma_s:
        raise CycleFailed(
            step, AlarmCode.ALIGNMENT_FAILED,
            f"the laser-to-robot latency is uncertain by {1e3 * est.sigma_s:.2f} ms (limit "
            f"{1e3 * cfg.max_latency_sigma_s:g} ms): the readings scatter; check the wall at the path's first corner",
        )  # fmt: skip
    return est
