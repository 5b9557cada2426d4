"""The alignment's choice of wall readings, as drawn: robot time and predicted plane error, spots against sweep.

From the nominal layout (the opening where the layout puts it, the camera and laser as drawn) and
``[process.align]``: the robot time between the standing spots (as listed, and in the fastest
order), the time of the sweep with its moves along the beam and of reading the laser's storage
out, and what each predicts for the wall
plane (:mod:`cellctl.align.reading_plan`). ``cellctl config check`` prints it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellctl.align import plan_spot_poses
from cellctl.align.laser_points import sweep_route
from cellctl.align.reading_plan import fastest_order, predicted_plane_error, standing_readings, sweep_readings
from cellctl.geometry.aiming import nominal_shooting_pose
from cellctl.config.feature import shot_aim_mm
from cellctl.config.devices import KeyenceLkgDevice
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import Pose

# The prediction's noise, one sigma along the wall normal: the LK-G500's repeatability per reading, and
# the robot's pose error per standing stop (half the IRB 7600's ISO 9283 RP of 0.1 mm).
LASER_SIGMA_MM = 0.002
ROBOT_SIGMA_MM = 0.05


@dataclass(frozen=True)
class WallPlan:
    """Robot time (s) and predicted plane error (1 sigma: normal in deg, offset at the corner in mm) of each choice."""

    spots: int
    spots_s: float
    fastest_order: list[int]
    fastest_s: float
    spots_error: tuple[float, float]
    sweep_s: float
    sweep_readings: int
    sweep_error: tuple[float, float]
    readout_s: float  # reading the laser's storage out after the sweep (its serial line)
    along_spots: int  # on the move with devices that cannot: the points along the path read standing (as taught)
    along_s: float  # robot time between them

    def lines(self) -> list[str]:
        return [
            f"stop and go: {self.spots} spots, {self.spots_s:.1f} s of robot time between them as listed"
            + ("" if self.fastest_s >= self.spots_s - 0.05 else
               f" ({self.fastest_s:.1f} s in the order {', '.join(map(str, self.fastest_order))})")  # fmt: skip
            + f"; plane +-{self.spots_error[0]:.4f} deg, +-{self.spots_error[1]:.3f} mm",
            f"on the move: {self.sweep_readings} readings along the sweep, {self.sweep_s:.1f} s of robot time "
            f"and {self.readout_s:.1f} s to read the laser's storage out; "
            f"plane +-{self.sweep_error[0]:.4f} deg, +-{self.sweep_error[1]:.3f} mm",
            f"(predicted 1 sigma with laser {LASER_SIGMA_MM:g} mm per reading, robot {ROBOT_SIGMA_MM:g} mm per standing stop)",
            f"on the move with devices that cannot (no storing laser, or no EGM): standing at the {self.along_spots} points "
            f"along the path that teaching reads, {self.along_s:.1f} s of robot time between them",
        ]


def wall_plan(config: CellConfig) -> WallPlan:
    """The choice of ``[process.align]`` against the nominal layout."""
    ac, layout, motion = config.process.align, config.layout, config.process.motion
    T0 = layout.opening.T_B_T_nominal()
    shoot = nominal_shooting_pose(T0, layout.camera_mount.T_H_C(), config.process.working_distance_mm, shot_aim_mm(config))
    r, l = np.asarray(layout.laser_mount.origin_mm, dtype=float), np.asarray(layout.laser_mount.direction, dtype=float)  # noqa: E741
    robot = layout.robot

    def poses(xy: tuple[tuple[float, float], ...]) -> list[Pose]:
        return plan_spot_poses(T0, xy, shoot[:3, :3], r, l, ac.laser_standoff_mm)

    spots = poses(ac.spots_mm)

    def between(i: int, j: int) -> float:
        return robot.move_time_s(spots[i], spots[j], motion.travel_speed_mm_s, motion.speed_deg_s)

    order, fastest = fastest_order(len(spots), between)
    sw, speed = ac.sweep, config.process.sweep_speed_mm_s(glass_on_gripper=True)  # the alignment carries the glass
    route = sweep_route(list(poses(sw.path_mm)), l, sw.approach_mm, beam_moves=0 if sw.fixed_latency_s is not None else 1)
    sweep_s = sum(robot.move_time_s(a, b, speed, motion.speed_deg_s) for a, b in zip(route, route[1:]))
    readout_s = sweep_s / sw.storage_cycle_s * readout_s_per_reading(config)  # everything stored from start to stop
    along = sweep_readings(sw.path_mm, speed * sw.storage_cycle_s)
    standing = poses(sw.points_along_mm())
    along_s = sum(robot.move_time_s(a, b, motion.travel_speed_mm_s, motion.speed_deg_s) for a, b in zip(standing, standing[1:]))
    noise = {"laser_sigma_mm": LASER_SIGMA_MM, "robot_sigma_mm": ROBOT_SIGMA_MM}
    return WallPlan(
        spots=len(spots), spots_s=sum(between(i, i + 1) for i in range(len(spots) - 1)), fastest_order=order,
        fastest_s=fastest, spots_error=predicted_plane_error(standing_readings(ac.spots_mm), **noise),
        sweep_s=float(sweep_s), sweep_readings=len(along.xy_mm), sweep_error=predicted_plane_error(along, **noise),
        readout_s=float(readout_s), along_spots=len(standing), along_s=float(along_s),
    )  # fmt: skip


def readout_s_per_reading(config: CellConfig) -> float:
    """Seconds to read one stored reading out of the laser: 9 characters of 10 bits at the LK-G's baud (RS-232C,
    8N1) on a real cell, the twin's ``sim.laser.readout_s_per_reading`` in simulation."""
    laser = config.devices.laser
    if isinstance(laser, KeyenceLkgDevice):
        return 9 * 10 / laser.baud
    return config.sim.laser.readout_s_per_reading
