"""One installation cycle: the sub-steps of Execute (paper sections 3 and 4.3).

:func:`run_cycle` drives the devices through their ports only:

1. align: laser spots around the opening, the wall plane, the aligned shooting pose C_Pos_1;
2. shoot: one image at the aligned pose;
3. compensate: the corner, eq. 16, T' and T2 = T1 @ T'; then verification shots at the corrected
   shooting pose until the residual offset is under the threshold;
4. install: approach, then the install pose ``T2 @ inv(T0) @ g_Pos_0``;
5. inspect: release, back off, measure the installed glass's gaps and flush (:mod:`cellctl.cell.inspect_step`).

Every figure goes to the :class:`CycleRecorder`; the install is announced to it (and must be
persisted) before the robot is commanded there, so a restart never repeats it. A failure raises
:class:`CycleFailed` with the step, the alarm code and a readable reason.
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from typing import Any

import numpy as np

from cellctl.align import (
    AlignmentError,
    AlignmentResult,
    compute_alignment,
    plan_spot_poses,
    readings_at_stops,
)
from cellctl.align.errors import WallFitScatter
from cellctl.cell.camera_frame import grab_checked
from cellctl.cell.cycle_failure import CycleFailed
from cellctl.cell.cycle_values import CellDevices, CycleCalibration, CycleRecorder, CycleResult, ShotRecord
from cellctl.cell.fine_motion import verification_move
from cellctl.cell.inspect_step import inspect_install
from cellctl.cell.laser_timing import LaserTiming
from cellctl.cell.sweep import sweep_readings, sweep_unavailable
from cellctl.compensate import (
    CorrectionLimitError,
    check_correction,
    corrected_workpiece_frame,
    deviation_in_frame,
    install_pose,
    shooting_pose_in,
    workpiece_frame_after_alignment,
)
from cellctl.config.cell import ProcessConfig
from cellctl.config.feature import ShotFeature
from cellctl.config.vision import VisionConfig
from cellctl.domain import AlarmCode, CycleStep
from cellctl.geometry.planar import PlanarOffset
from cellctl.geometry.pose import Pose, invert_pose, make_pose, mean_pose
from cellctl.ports import (
    CartesianPose,
    DeviceError,
    LaserStatus,
    MotionKind,
    MotionRequest,
    UnreachableTarget,
)
from cellctl.vision import CornerFeatures, annotate, offset_from_map
from cellctl.vision.annotate_arc import annotate_arc
from cellctl.vision.arc_corner import ArcCornerMeasurement
from cellctl.vision.feature import FeatureShot, detect_feature, first_shot_limits
from cellctl.vision.offset import turn_measured


def _offset_size(offset: PlanarOffset) -> tuple[float, float]:
    return float(np.hypot(offset.dx_mm, offset.dy_mm)), abs(offset.dtheta_rad)


class CycleRun:
    """The state of one cycle while it runs (kept off the module level: no globals)."""

    def __init__(
        self,
        devices: CellDevices,
        cal: CycleCalibration,
        process: ProcessConfig,
        vision: VisionConfig,
        recorder: CycleRecorder,
        laser_timing: LaserTiming | None = None,
        feature: ShotFeature | None = None,
    ) -> None:
        self.dev = devices
        self.feature = feature or ShotFeature()  # the corner, or the arc for a large corner radius
        self.cal = cal
        self.process = process
        self.vision = vision
        self.rec = recorder
        self.motion = process.motion
        self.glass_on_gripper = True  # the cycle starts with a glass on the gripper; the inspection releases it
        self.sweep_latency_s: float | None = None  # this cycle's laser-to-robot latency, once a sweep timed it
        self.laser_timing = laser_timing if laser_timing is not None else LaserTiming()  # kept from cycle to cycle
        self._last_shot = ShotRecord(-1, PlanarOffset(0.0, 0.0, 0.0), 0.0)
        self._last_image: tuple[int, np.ndarray, FeatureShot, PlanarOffset | None] | None = None

    async def move(
        self, step: CycleStep, T: Pose, *, kind: MotionKind = "linear", fine: bool = False, speed_mm_s: float | None = None
    ) -> Pose:
        travel_mm_s, turn_deg_s = self.motion.speeds(glass_on_gripper=self.glass_on_gripper)
        speed = speed_mm_s or (self.motion.fine_speed_mm_s if fine else travel_mm_s)
        request = MotionRequest(CartesianPose.from_matrix(T), kind, speed, turn_deg_s)
        try:
            reached = await self.dev.robot.move(request, timeout_s=self.motion.move_timeout_s)
        except UnreachableTarget as err:
            raise CycleFailed(step, AlarmCode.CORRECTION_LIMIT_EXCEEDED, f"target out of reach: {err}") from err
        except DeviceError as err:
            raise CycleFailed(step, AlarmCode.ROBOT_FAULT, f"robot move failed: {err}") from err
        return reached.to_matrix()

    def limit(self, step: CycleStep, taught: Pose, corrected: Pose, what: str, *, verify: bool = False) -> None:
        lim = self.process.limits
        max_mm = lim.max_verify_step_mm if verify else lim.max_correction_mm
        max_deg = lim.max_verify_step_deg if verify else lim.max_correction_deg
        try:
            check_correction(taught, corrected, max_translation_mm=max_mm, max_rotation_rad=np.radians(max_deg), what=what)
        except CorrectionLimitError as err:
            raise CycleFailed(step, AlarmCode.CORRECTION_LIMIT_EXCEEDED, str(err)) from err

    async def align(self) -> tuple[AlignmentResult, Pose]:
        step = CycleStep.ALIGN
        await self.rec.step_started(step)
        cfg, cal = self.process.align, self.cal
        unavailable = sweep_unavailable(self) if cfg.mode == "on_the_fly" else None
        at_rest: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # on the move: the plane's offset from the sweep's stops
        if cfg.mode == "on_the_fly" and unavailable is None:
            poses, distances, figures, at_rest = await sweep_readings(self)
        elif unavailable is not None:
            # Asked for, but these devices cannot: read standing where teaching read for the sweep (its offset at the
            # path's corners), so the taught plane and this one share the robot's errors; the record says why.
            poses, distances, figures, at_rest = await self._spot_readings(cfg.wall_spots_mm(), cfg.wall_stops())
            figures |= {"on_the_fly_unavailable": unavailable, "spots_along": "process.align.sweep.path_mm"}
        else:
            poses, distances, figures, _ = await self._spot_readings(cfg.spots_mm)
        try:
            result = compute_alignment(
                poses,
                distances,
                cal.laser_r,
                cal.laser_l,
                cal.T_H_C,
                self.process.working_distance_mm,
                T_B_H_current=cal.taught.C_Pos_0,
                range_mm=cal.laser_range_mm,
                inlier_threshold_mm=cfg.inlier_threshold_mm,
                max_rms_mm=cfg.max_rms_mm,
                min_collinearity=cfg.min_collinearity,
                at_rest=at_rest,
                min_rest_points=10 if unavailable is None else len(cfg.wall_stops()),  # a sweep's many, or one a corner
            )
        except AlignmentError as err:
            why = str(err)
            if isinstance(err, WallFitScatter) and figures.get("mode") == "on_the_fly":  # the passes of a path part too
                why += (f"; on the move, or the laser's latency is off by milliseconds (this sweep paired its readings "
                        f"at {figures['latency_ms']:.2f} ms, {figures.get('latency')})")  # fmt: skip
            raise CycleFailed(step, AlarmCode.ALIGNMENT_FAILED, why) from err
        self.limit(step, cal.taught.C_Pos_0, result.T_B_H_aligned, "aligned shooting pose")
        wall = result.wall
        # standing, a rejected reading is named by its spot (as figures["spots"] are), not by its place among the readings
        spot_of = [s["index"] for s in figures["spots"] if s["status"] == LaserStatus.OK.value] if "spots" in figures else None
        await self.rec.step_figures(
            step,
            figures | {
                "rejected": [{"index": r.index if spot_of is None else spot_of[r.index], "residual_mm": r.residual_mm,
                              "reason": r.reason} for r in wall.rejected],  # fmt: skip
                "normal_B": wall.normal.tolist(),
                "fit_rms_mm": wall.plane.rms,
                "fit_max_residual_mm": wall.plane.max_residual,
                "normal_uncertainty_deg": None if wall.uncertainty is None else float(np.degrees(wall.uncertainty.rms_rad)),
                "flange_turn_deg": float(np.degrees(result.rotation_rad)),
                "lm_vs_minimal_axis_rad": result.axis_agreement_rad,
                "distance_correction_mm": result.distance.delta_d_mm,
            } | ({} if wall.rest_shift_mm is None else {"rest_shift_mm": wall.rest_shift_mm}),
        )
        C_Pos_1 = await self.move(step, result.T_B_H_aligned)
        return result, C_Pos_1

    async def _spot_readings(
        self, spots_mm: Sequence[Sequence[float]], stops: Sequence[int] = ()
    ) -> tuple[np.ndarray, np.ndarray, dict[str, Any], tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
        """Stop at each spot (mm in T0) and read once (stop and go): the flange poses (N, 4, 4), distances (N,), the
        figures, and the readings at ``stops`` (spot indices, each its own stop) as ``compute_alignment``'s ``at_rest``."""
        step, cfg, cal = CycleStep.ALIGN, self.process.align, self.cal
        planned = plan_spot_poses(
            cal.taught.T0, spots_mm, cal.taught.C_Pos_0[:3, :3], cal.laser_r, cal.laser_l, cfg.laser_standoff_mm
        )
        poses, distances, spots = [], [], []
        for i, T in enumerate(planned):
            reached = await self.move(step, T, kind="joint" if i == 0 else "linear")
            try:
                reading = await self.dev.laser.read(timeout_s=self.motion.read_timeout_s)
            except DeviceError as err:
                raise CycleFailed(step, AlarmCode.LASER_READ_FAILED, f"laser reading at spot {i} failed: {err}") from err
            spots.append({"index": i, "status": reading.status.value, "distance_mm": reading.distance_mm})
            if reading.status is LaserStatus.OK and reading.distance_mm is not None:
                poses.append(reached)
                distances.append(reading.distance_mm)
        missing = [s["index"] for s in spots if s["status"] != LaserStatus.OK.value]
        need = min(4, len(planned))  # of four or more, a bad reading can be told from the others (align.wall)
        if len(distances) < need:
            raise CycleFailed(
                step,
                AlarmCode.ALIGNMENT_FAILED,
                f"only {len(distances)} of {len(planned)} laser spots gave a distance (spots {missing} had none; "
                f"{need} are needed, so that a bad one can be found); is the car body in position?",
            )
        if unread := [k for k in stops if k in missing]:
            raise CycleFailed(
                step,
                AlarmCode.ALIGNMENT_FAILED,
                f"no laser reading at spots {unread}, corners of process.align.sweep.path_mm: the wall's distance is "
                "taken at every corner, as teaching took it; is the car body in position?",
            )
        figures = {"mode": "stop_and_go", "spots": spots, "spots_without_reading": missing} | ({"stops": list(stops)} if stops else {})
        read = [s["index"] for s in spots if s["status"] == LaserStatus.OK.value]
        H, d = np.stack(poses), np.array(distances)
        return H, d, figures, readings_at_stops(H, d, [read.index(k) for k in stops])

    async def shoot_and_compensate(self, C_Pos_1: Pose) -> tuple[Pose, tuple[ShotRecord, ...]]:
        """The first shot at C_Pos_1, then verification shots at the corrected shooting pose.

        Every shot re-anchors on the pose the robot reports and turns the measured offset into an
        estimate of the workpiece frame (T2 = T1 @ T'). Verification shots are averaged; the loop
        ends when the latest residual is under the threshold and enough shots were taken. If the
        first shot finds the corner only roughly (too near the image border to measure, or too little
        of an arc in view), the camera re-aims at it once and shoots again.
        """
        cal, verify = self.cal, self.process.verify
        T1 = workpiece_frame_after_alignment(cal.taught, C_Pos_1)
        m, offset = await self._measure(0, first=True)
        coarse = getattr(m.measurement, "coarse_corner_px", None)  # a rough find (corner or arc)
        if offset is None and coarse is not None:
            rough = CornerFeatures(
                float(coarse[0]), float(coarse[1]), cal.template.theta_rad, cal.template.top_angle_rad, cal.template.right_angle_rad
            )
            aim = offset_from_map(cal.template, rough, cal.nine_point)
            await self.rec.step_figures(CycleStep.COMPENSATE, {"re_aim_mm": [aim.dx_mm, aim.dy_mm], "refusal": m.message})
            target = shooting_pose_in(cal.taught, corrected_workpiece_frame(T1, aim))
            self.limit(CycleStep.COMPENSATE, C_Pos_1, target, "re-aimed shooting pose")
            T1 = workpiece_frame_after_alignment(cal.taught, await self.move(CycleStep.COMPENSATE, target))
            m, offset = await self._measure(0, first=True)
        T_est = await self._estimate(0, m, offset, T1)
        # The move after verification shot 1 corrects shot 0's error. An arc shot without an edge the template
        # has (top edge out of view, or only the right edge) corrected no turn, and a shot taken with the relaxed
        # first-shot limits (fewer edge points, a looser sigma: an arc's centre off the image turned 0.55 deg
        # short) may be off by more than a verification step: that move may still be a first correction's size.
        first_turned = m.features is not None and turn_measured(cal.template, m.features) and not self._first_shot_relaxed()
        shots: list[ShotRecord] = [self._last_shot]
        estimates: list[Pose] = []
        moved_mm = turned_rad = float("nan")
        moves: list[str] = []  # how each verification move went: by EGM or by RAPID (and why)
        for k in range(1, verify.max_shots + 1):
            here = await self._current_pose(CycleStep.COMPENSATE)
            target = shooting_pose_in(cal.taught, T_est)
            self.limit(CycleStep.COMPENSATE, here, target, "verification shooting pose", verify=k > (1 if first_turned else 2))
            reached, how = await verification_move(self, CycleStep.COMPENSATE, target)
            moves.append(how)
            m, offset = await self._measure(k)
            estimates.append(await self._estimate(k, m, offset, workpiece_frame_after_alignment(cal.taught, reached)))
            shots.append(self._last_shot)
            T_est = mean_pose(np.stack(estimates))
            moved_mm, turned_rad = _offset_size(self._last_shot.offset)
            if k >= verify.min_shots and moved_mm <= verify.residual_mm and turned_rad <= np.radians(verify.residual_deg):
                await self.rec.step_figures(
                    CycleStep.COMPENSATE, {"converged": True, "averaged_shots": len(estimates), "verification_moves": moves}
                )
                await self.annotate_last()
                return T_est, tuple(shots)
        await self.rec.step_figures(CycleStep.COMPENSATE, {"verification_moves": moves})
        await self.annotate_last()
        raise CycleFailed(
            CycleStep.COMPENSATE,
            AlarmCode.RESIDUAL_OVER_LIMIT,
            f"after {verify.max_shots} verification shots the corner still moves {moved_mm:.3f} mm and "
            f"{np.degrees(turned_rad):.4f} deg between shots (limits {verify.residual_mm} mm, "
            f"{verify.residual_deg} deg): the robot does not hold its pose or the image is unstable",
        )

    def _first_shot_relaxed(self) -> bool:
        """Whether the first shot's limits (process.verify.first_shot_*) are looser than a verification shot's."""
        verify, lim, arc = self.process.verify, self.vision.limits, self.feature.arc
        looser = verify.first_shot_sigma_px > lim.max_corner_sigma_px or verify.first_shot_min_edge_points < lim.min_edge_points
        if arc is not None:  # the arc's first-shot limits only ever loosen (a larger sigma, a shorter coverage)
            looser |= first_shot_limits(self.vision, arc, verify.first_shot_sigma_px, verify.first_shot_min_edge_points)[1] != arc
        return looser

    async def _measure(self, index: int, *, first: bool = False) -> tuple[FeatureShot, PlanarOffset | None]:
        """Grab, find the corner (or the arc) and turn it into T' (None when the detector refused)."""
        cal = self.cal
        await self.rec.step_started(CycleStep.SHOOT)
        frame = await grab_checked(self.dev.camera, cal.lens, CycleStep.SHOOT, timeout_s=self.motion.grab_timeout_s, what="no image")
        await self.rec.step_started(CycleStep.COMPENSATE)
        vision, arc = self.vision, self.feature.arc
        if first:  # the first shot aims the verification shots; they carry the precision
            verify = self.process.verify
            vision, arc = first_shot_limits(vision, arc, verify.first_shot_sigma_px, verify.first_shot_min_edge_points)
        radius = self.feature.corner_radius
        m = await asyncio.to_thread(detect_feature, frame.image, cal.lens, vision, arc, need_orientation=not first,
                                   corner_radius=radius, taught=cal.taught_profile)  # fmt: skip
        point = self.feature.point_mm
        offset = offset_from_map(cal.template, m.features, cal.nine_point, point) if m.features is not None else None
        self._last_image = (index, frame.image, m, offset)
        if offset is None:  # a refusal is always shown, for whoever has to find out why
            await self.annotate_last()
        return m, offset

    async def annotate_last(self) -> None:
        """The annotated picture of the latest shot, recorded (only refusals and final shots get one)."""
        if self._last_image is None:
            return
        index, image, m, offset = self._last_image
        self._last_image = None
        taught = self.cal.template
        if isinstance(m.measurement, ArcCornerMeasurement):
            png = await asyncio.to_thread(annotate_arc, image, m.measurement, self.cal.lens, self.vision.roi, taught=taught, offset=offset)
        else:
            png = await asyncio.to_thread(annotate, image, m.measurement, self.cal.lens, taught=taught, offset=offset)
        await self.rec.image(f"shot{index}", png)

    async def _estimate(self, index: int, m: FeatureShot, offset: PlanarOffset | None, T1: Pose) -> Pose:
        """T1 corrected by the shot's offset; a refused shot fails the cycle with the detector's reason."""
        if offset is None:
            raise CycleFailed(CycleStep.COMPENSATE, AlarmCode.CORNER_NOT_FOUND, m.message)
        assert m.features is not None
        self._last_shot = ShotRecord(index, offset, float(m.sigma_px or 0.0))
        await self.rec.step_figures(
            CycleStep.COMPENSATE,
            {
                "shot": index,
                **({"feature": "arc"} if m.kind == "arc" else {}),  # the arc's centre for a large corner radius
                "corner_px": [m.features.u_px, m.features.v_px],
                "theta_deg": float(np.degrees(m.features.theta_rad)) if np.isfinite(m.features.theta_rad) else None,
                "corner_sigma_px": m.sigma_px,
                "offset_mm": [offset.dx_mm, offset.dy_mm],
                "offset_deg": float(np.degrees(offset.dtheta_rad)),
            },
        )
        return corrected_workpiece_frame(T1, offset)

    async def _current_pose(self, step: CycleStep) -> Pose:
        try:
            return (await self.dev.robot.read_pose(timeout_s=self.motion.read_timeout_s)).to_matrix()
        except DeviceError as err:
            raise CycleFailed(step, AlarmCode.ROBOT_FAULT, f"cannot read the robot pose: {err}") from err

    async def install(self, T2: Pose, offset: Pose | None = None) -> tuple[Pose, Pose]:
        """Approach, then the install pose; ``offset`` (the glass's systematic deviation in T) is taken out."""
        step = CycleStep.INSTALL
        taught = self.cal.taught
        T_target = T2 if offset is None else T2 @ invert_pose(offset)
        target = install_pose(taught, T_target)
        self.limit(step, taught.g_Pos_0, target, "install pose")
        approach = T_target @ make_pose(np.eye(3), [0.0, 0.0, -self.motion.approach_mm]) @ taught.T_T0_gpos0
        await self.rec.install_started(CartesianPose.from_matrix(target))
        await self.move(step, approach, kind="joint")
        reached = await self.move(step, target, fine=True)
        return target, reached


async def run_cycle(
    devices: CellDevices,
    cal: CycleCalibration,
    process: ProcessConfig,
    vision: VisionConfig,
    recorder: CycleRecorder,
    *,
    install_offset: Pose | None = None,
    laser_timing: LaserTiming | None = None,
    feature: ShotFeature | None = None,
) -> CycleResult:
    """Run one cycle through align, shoot, compensate (with verification), install and inspect.

    ``install_offset`` is the closed loop's estimate of the glass's systematic deviation in T
    (a small pose); the install target takes it out. ``laser_timing`` is the latency the cell keeps
    between sweeps (None: this cycle times its own). ``feature`` is what the recipe's shots measure
    (cellctl.config.feature.shot_feature; None: the corner).
    """
    run = CycleRun(devices, cal, process, vision, recorder, laser_timing, feature)
    alignment, C_Pos_1 = await run.align()
    T2, shots = await run.shoot_and_compensate(C_Pos_1)
    target, reached = await run.install(T2, install_offset)
    dt, dr = deviation_in_frame(cal.taught.T0, T2)
    await recorder.step_figures(
        CycleStep.INSTALL,
        {
            "workpiece_correction_mm": dt.tolist(),
            "workpiece_correction_deg": np.degrees(dr).tolist(),
            "install_target": _pose_fields(target),
            "install_reached": _pose_fields(reached),
            "target_vs_reached_mm": float(np.linalg.norm((invert_pose(target) @ reached)[:3, 3])),
        },
    )
    measured = await inspect_install(run, T2, reached) if process.inspect.enabled else None
    return CycleResult(dt, dr, target, reached, alignment, shots, measured, install_offset)


def _pose_fields(T: Pose) -> dict[str, list[float]]:
    p = CartesianPose.from_matrix(T)
    return {"position_mm": list(p.position_mm), "quaternion_wxyz": list(p.quaternion_wxyz)}
