"""Calibration and teaching taken from the twin's truth (the "true calibrations" of the error budget).

A cell calibrated from measured data carries the calibrations' own errors; this oracle gives the
cycle the true camera model, hand-eye and laser, so the remaining error is what teaching and the
cycle add. Teaching follows the paper's procedure (4.3 step 1) in the twin, with the car body at
its nominal posture: the shooting pose C_Pos_0 by laser alignment (so the alignment's systematic
errors, e.g. the robot's accuracy field across the spots, are the same in teaching and production
and cancel), the template features by the real corner detector there, each averaged over
``repeats`` fresh robot moves; the install pose g_Pos_0 as a perfect operator would record it (the
belief that truly seats the glass); T0 the true workpiece frame.
"""

from __future__ import annotations

import copy
import threading
from collections import OrderedDict
from datetime import datetime
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.align import AlignmentResult, compute_alignment, plan_spot_poses, readings_at_stops
from cellctl.cell.cycle_values import CycleCalibration
from cellctl.compensate import TaughtPoses
from cellctl.config.feature import shot_aim_mm, shot_feature
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import Pose, apply_pose, invert_pose, make_pose, mean_pose
from cellctl.sim.rig import SimRig
from cellctl.sim.world import World, nominal_world
from cellctl.vision import CornerFeatures, Lens, fit_affine_map
from cellctl.vision.feature import detect_feature

# The nine-point target's dots, in the workpiece plane around the aim (mm).
NINE_POINTS_MM = np.array([(x, y) for y in (-50.0, 0.0, 50.0) for x in (-50.0, 0.0, 50.0)])


def teaching_alignment(
    rig: SimRig, config: CellConfig, T0: Pose, C_guess: Pose, *, laser_r: NDArray[np.float64],
    laser_l: NDArray[np.float64], T_H_C: Pose, range_mm: tuple[float, float],
) -> AlignmentResult:
    """One laser alignment (paper section 3) around the guessed shooting pose, as the cycle does it,
    through the given laser ray and hand-eye (the truth for the oracle, a calibration's for the budget):
    its aligned shooting pose and wall plane."""
    cell, align = rig.cell, config.process.align
    planned = plan_spot_poses(T0, align.wall_spots_mm(), C_guess[:3, :3], laser_r, laser_l, align.laser_standoff_mm)
    distances = []
    for k, X in enumerate(planned):
        cell.execute(X)
        status, d = cell.laser_reading()
        if d is None:
            raise RuntimeError(f"teaching: laser spot {k} gave no distance ({status.value})")
        distances.append(d)
    stops = align.wall_stops()  # on the move: the plane's offset from the path's corners, as the cycle's from its stops
    result = compute_alignment(
        planned, np.array(distances), laser_r, laser_l, T_H_C, config.process.working_distance_mm,
        T_B_H_current=C_guess, range_mm=range_mm, at_rest=readings_at_stops(planned, distances, stops),
        min_rest_points=len(stops),
    )  # fmt: skip
    return result


def template_at(rig: SimRig, config: CellConfig, C_Pos_0: Pose, world: World, lens: Lens, repeats: int) -> CornerFeatures:
    """The mean feature (corner or arc) of ``repeats`` shots, each after a fresh move to C_Pos_0, through ``lens``."""
    features = []
    feature = shot_feature(config)
    for _ in range(repeats):
        T_true = rig.cell.execute(C_Pos_0)
        frame = rig.renderer.render(T_true @ rig.cell.T_H_C, world, rng=rig.teach_rng)
        measured = detect_feature(frame.image, lens, config.vision, feature.arc, corner_radius=feature.corner_radius)
        if measured.features is None:
            raise RuntimeError(f"teaching: the template shot was refused: {measured.message}")
        features.append(measured.features)
    a = np.array([[f.u_px, f.v_px, f.theta_rad, f.top_angle_rad, f.right_angle_rad] for f in features]).mean(axis=0)
    return CornerFeatures(*(float(v) for v in a))


def oracle_calibration(rig: SimRig, config: CellConfig, *, repeats: int = 8) -> CycleCalibration:
    """A cycle calibration from the twin's truth, taught with the car body at its nominal posture."""
    sim = config.sim
    cell = rig.cell
    current = cell.world()
    world = nominal_world(sim.world)
    T_H_C = sim.camera.hand_eye.T_H_C()
    lens = Lens.from_intrinsics(sim.camera.intrinsics)
    T0 = world.T_B_T
    # The guess: the camera's axes on T's, its optical centre 400 mm in front of the aim (the corner, or beside the arc).
    aim = shot_aim_mm(config)
    T_B_C0 = T0 @ make_pose(np.eye(3), [aim[0], aim[1], -config.process.working_distance_mm])
    C_guess = cell.robot_model.command_for(T_B_C0 @ invert_pose(T_H_C))
    laser = sim.laser
    ray = {"laser_r": laser.r, "laser_l": laser.l, "T_H_C": T_H_C, "range_mm": (laser.range_min_mm, laser.range_max_mm)}
    try:
        cell.place_car_body(world)
        C_Pos_0 = mean_pose(np.stack([teaching_alignment(rig, config, T0, C_guess, **ray).T_B_H_aligned for _ in range(repeats)]))
        template = template_at(rig, config, C_Pos_0, world, lens, repeats)
        g_Pos_0 = cell.install_command()
        # The nine-point map: the camera model maps the wall plane at the taught pose.
        T_B_C = cell.robot_model.deform(C_Pos_0) @ T_H_C
    finally:
        cell.place_car_body(current)
    K = lens.camera_matrix
    wall_B = apply_pose(T0, np.column_stack([NINE_POINTS_MM + np.asarray(aim), np.zeros(len(NINE_POINTS_MM))]))
    in_C = apply_pose(invert_pose(T_B_C), wall_B)
    ideal_px = (in_C[:, :2] / in_C[:, 2:3]) * np.array([K[0, 0], K[1, 1]]) + np.array([K[0, 2], K[1, 2]])
    return CycleCalibration(
        lens=lens,
        T_H_C=T_H_C,
        laser_r=laser.r,
        laser_l=laser.l,
        laser_range_mm=config.process.align.laser_range_mm,
        nine_point=fit_affine_map(ideal_px, NINE_POINTS_MM),
        taught=TaughtPoses(T0, C_Pos_0, g_Pos_0),
        template=template,
    )


# Teaching from the truth is deterministic in (config, seed) and takes seconds (16 rendered and
# measured shots): each process teaches a twin once and hands out copies.
_TAUGHT: OrderedDict[tuple[int, str], CycleCalibration] = OrderedDict()
_TAUGHT_MAX = 32
_TAUGHT_LOCK = threading.Lock()
_TEACHING: dict[tuple[int, str], threading.Lock] = {}


def taught_once(config: CellConfig, seed: int) -> CycleCalibration:
    """:func:`oracle_calibration` on a twin of ``config.sim`` and ``seed`` (a recipe's view), taught once per process.

    The key is every section teaching reads (``layout``, ``process``, ``vision``, ``sim``), so any
    change to them teaches anew; each caller gets its own copy.
    """
    key = (int(seed), config.model_dump_json(include={"mode", "layout", "process", "vision", "sim"}))
    with _TAUGHT_LOCK:
        teaching = _TEACHING.setdefault(key, threading.Lock())
    with teaching:  # one twin teaches a key; others wait for it, other keys teach meanwhile
        with _TAUGHT_LOCK:
            cal = _TAUGHT.get(key)
        if cal is None:
            cal = oracle_calibration(SimRig(config.sim, seed=seed), config)
            with _TAUGHT_LOCK:
                _TAUGHT[key] = cal
                while len(_TAUGHT) > _TAUGHT_MAX:
                    _TAUGHT.popitem(last=False)
        with _TAUGHT_LOCK:
            _TEACHING.pop(key, None)
    return copy.deepcopy(cal)


class OracleCalibrationSource:
    """A CalibrationSource that is always ready, built from the twin's truth on first use."""

    def __init__(self, rig: SimRig, config: CellConfig) -> None:
        self._rig = rig
        self._config = config
        self._cals: dict[str, CycleCalibration] = {}  # by recipe
        self._lock = threading.Lock()

    def problems(self, recipe: str | None = None, *, now: datetime | None = None) -> list[str]:
        return []

    def cycle_calibration(self, recipe: str | None = None) -> CycleCalibration:
        """Taught once per recipe, on a twin of its own with the cell's seed (the same robot, mountings,
        and a car body of the recipe): teaching never moves the cell's arm under a running cycle or a
        stop, nor draws from the cell's noise streams."""
        name = recipe or self._config.default_recipe
        with self._lock:
            if name not in self._cals:  # the twin's computing, not a real cell's (it reads its set): off the cell's clock
                with self._rig.cell.timeline.unclocked():
                    self._cals[name] = taught_once(self._config.for_recipe(name), self._rig.cell.seed)
            return self._cals[name]

    def summary(self, *, now: datetime | None = None) -> dict[str, Any]:
        first = self._cals.get(self._config.default_recipe)
        return {"source": "twin truth (oracle)", "template_px": None if first is None else [first.template.u_px, first.template.v_px],
                "recipes": {r.name: {"ready": True, "taught": True, "problems": []} for r in self._config.process.recipes}}  # fmt: skip

    def history(self) -> list[dict[str, Any]]:
        return []

    def untaught(self, recipe: str) -> str | None:
        return None  # the oracle teaches every recipe from the truth

    def reference(self, recipe: str | None = None) -> dict[str, Any]:
        return {"source": "twin truth (oracle)", "version": None}
