"""Calibration and teaching taken from the twin's truth (the "true calibrations" of the error budget).

A cell calibrated from measured data carries the calibrations' own errors; this oracle gives the
cycle the true camera model, hand-eye and laser, and a teaching done with perfect hands, so the
remaining error is what the cycle itself adds. Poses are robot beliefs, as teaching records them:
the pose that truly puts the camera (or the glass) where it should be, through the robot's own
absolute-accuracy error. The template features come from the real corner detector on a
noise-free render at the taught shooting pose, as teaching would measure them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cellctl.cell.cycle import CycleCalibration
from cellctl.compensate import TaughtPoses
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import apply_pose, invert_pose, make_pose
from cellctl.sim.rig import SimRig
from cellctl.sim.world import nominal_world
from cellctl.vision import Lens, detect_corner, fit_affine_map

# The nine-point target's dots, in the workpiece plane around the corner (mm).
NINE_POINTS_MM = np.array([(x, y) for y in (-50.0, 0.0, 50.0) for x in (-50.0, 0.0, 50.0)])


def oracle_calibration(rig: SimRig, config: CellConfig) -> CycleCalibration:
    """A cycle calibration from the twin's truth, taught with the car body at its nominal posture."""
    sim = config.sim
    cell = rig.cell
    current = cell.world()
    world = nominal_world(sim.world)
    T_H_C = sim.camera.hand_eye.T_H_C()
    lens = Lens.from_intrinsics(sim.camera.intrinsics)
    T0 = world.T_B_T
    # Standard shooting pose: the camera's axes on T's, its optical centre over the corner.
    T_B_C0 = T0 @ make_pose(np.eye(3), [0.0, 0.0, -config.process.working_distance_mm])
    C_Pos_0 = cell.robot_model.command_for(T_B_C0 @ invert_pose(T_H_C))
    try:
        cell.place_car_body(world)
        g_Pos_0 = cell.install_command()
    finally:
        cell.place_car_body(current)
    frame = rig.renderer.render(T_B_C0, world, noise=False)
    measured = detect_corner(frame.image, lens, config.vision)
    if not measured.ok:
        raise RuntimeError(f"the oracle's template shot was refused: {measured.message}")
    K = lens.camera_matrix
    wall_B = apply_pose(T0, np.column_stack([NINE_POINTS_MM, np.zeros(len(NINE_POINTS_MM))]))
    in_C = apply_pose(invert_pose(T_B_C0), wall_B)
    ideal_px = (in_C[:, :2] / in_C[:, 2:3]) * np.array([K[0, 0], K[1, 1]]) + np.array([K[0, 2], K[1, 2]])
    laser = sim.laser
    return CycleCalibration(
        lens=lens,
        T_H_C=T_H_C,
        laser_r=laser.r,
        laser_l=laser.l,
        laser_range_mm=(laser.range_min_mm, laser.range_max_mm),
        nine_point=fit_affine_map(ideal_px, NINE_POINTS_MM),
        taught=TaughtPoses(T0, C_Pos_0, g_Pos_0),
        template=measured.features,
    )


class OracleCalibrationSource:
    """A CalibrationSource that is always ready, built from the twin's truth on first use."""

    def __init__(self, rig: SimRig, config: CellConfig) -> None:
        self._rig = rig
        self._config = config
        self._cal: CycleCalibration | None = None

    def problems(self) -> list[str]:
        return []

    def cycle_calibration(self) -> CycleCalibration:
        if self._cal is None:
            self._cal = oracle_calibration(self._rig, self._config)
        return self._cal

    def summary(self) -> dict[str, Any]:
        return {"source": "twin truth (oracle)", "template_px": None if self._cal is None else [self._cal.template.u_px, self._cal.template.v_px]}

    async def calibrate(self) -> None:
        self.cycle_calibration()
