"""Whether the robot reaches the poses a window needs, planned from the nominal layout (checked at load).

The poses: the shooting pose (the camera square to the wall at ``process.working_distance_mm`` before the shot's aim),
the laser's wall readings at ``process.align.laser_standoff_mm`` in its orientation (the spots, or on the move the
sweep's corners and its move out along the beam), and in the simulated cell the install pose and its approach for the
glass on the gripper (``[sim.glass]``). They are planned as teaching and the cycle plan them, through the drawn camera
and laser mountings (``[layout]``), and each is checked by :meth:`RobotEnvelope.reach_problem` of ``[layout.robot]``:
the check the commissioning plans make and the twin's robot raises its ReachError by. The poses come from
:mod:`cellctl.geometry.aiming`, as the planners' do.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cellctl.config.feature import shot_aim_mm
from cellctl.config.layout import _vec
from cellctl.geometry.aiming import flange_pose_at_spot, nominal_shooting_pose
from cellctl.geometry.pose import Pose, invert_pose, make_pose

if TYPE_CHECKING:
    from cellctl.config.schema import CellConfig


@dataclass(frozen=True)
class NominalPose:
    """A flange pose T_B_H (mm, robot base) a window needs, with the setting that places it and what it is for."""

    setting: str  # the field the message starts with (a recipe's view names it as the recipe's)
    what: str  # the pose, for the envelope's message
    fix: str  # what to change, beyond the envelope's "bring the car body or the target closer"
    T_B_H: Pose


def shooting_pose(config: CellConfig, aim: tuple[float, float]) -> Pose:
    """The nominal shooting pose T_B_H before T's point ``aim`` (x, y; mm: ``shot_aim_mm``), as teaching plans it."""
    o, mount = config.layout.opening, config.layout.camera_mount
    return nominal_shooting_pose(o.T_B_T_nominal(), mount.T_H_C(), config.process.working_distance_mm, aim)


def wall_reading_poses(config: CellConfig, shoot: Pose) -> list[NominalPose]:
    """The laser's pose at each place the alignment reads the wall (T0 x, y; mm) in the shooting pose's
    orientation, the spot at ``laser_standoff_mm`` (eq. 1 backwards, as plan_spot_poses): the spots, or the
    sweep's corners and its first corner's move out along the beam."""
    ac, o, mount = config.process.align, config.layout.opening, config.layout.laser_mount
    T0, R = o.T_B_T_nominal(), shoot[:3, :3]
    r, l = mount.r, mount.l  # noqa: E741
    moving = ac.mode == "on_the_fly"
    places = ac.sweep.path_mm if moving else ac.spots_mm
    field = ac.wall_setting()
    fix = f"move it, or the opening (its corner_position_mm = {_vec(o.corner_position_mm)}), into the robot's working range"
    out = []
    for k, (x, y) in enumerate(places):
        spot = T0[:3, :3] @ np.array([x, y, 0.0]) + T0[:3, 3]
        T = flange_pose_at_spot(spot, R, r, l, ac.laser_standoff_mm)
        what = f"the laser's pose that reads it at process.align.laser_standoff_mm = {ac.laser_standoff_mm:g}"
        out.append(NominalPose(f"{field}[{k}] [{x:g}, {y:g}]", what, fix, T))
    if moving and ac.sweep.fixed_latency_s is None:  # the laser is timed moving out along the beam at the first corner
        back = out[0].T_B_H.copy()
        back[:3, 3] -= (R @ l) * ac.sweep.approach_mm
        out.append(NominalPose(f"{field}[0] [{places[0][0]:g}, {places[0][1]:g}]",
                               f"the move {ac.sweep.approach_mm:g} mm out along the beam that times the laser there "
                               "(process.align.sweep.approach_mm)", fix, back))  # fmt: skip
    return out


def install_poses(config: CellConfig) -> list[NominalPose]:
    """The simulated cell's install pose (the glass's corner frame G of ``[sim.glass]`` onto T) and its approach
    ``process.motion.approach_mm`` before it, as the cycle moves them; none in a real cell (its gripper is taught)."""
    if config.mode != "sim":
        return []
    glass, o = config.sim.glass, config.layout.opening
    T0, H_G = o.T_B_T_nominal(), invert_pose(glass.T_H_G())
    setting = f"sim.glass.corner_in_flange_mm = {_vec(glass.corner_in_flange_mm)}"
    fix = (f"hold the glass otherwise in the flange, or move the opening (its corner_position_mm = "
           f"{_vec(o.corner_position_mm)}) into the robot's working range")  # fmt: skip
    approach = config.process.motion.approach_mm
    return [
        NominalPose(setting, "the install pose that puts this glass's corner onto the opening's", fix, T0 @ H_G),
        NominalPose(setting, f"the install's approach (process.motion.approach_mm = {approach:g} before it)", fix,
                    T0 @ make_pose(np.eye(3), [0.0, 0.0, -approach]) @ H_G),
    ]  # fmt: skip


def nominal_poses(config: CellConfig) -> list[NominalPose]:
    """Every pose the window needs, the shooting pose first (it names the opening's place)."""
    o, wd = config.layout.opening, config.process.working_distance_mm
    aim = shot_aim_mm(config)
    shoot = shooting_pose(config, aim)
    first = NominalPose(
        f"layout.opening.corner_position_mm = {_vec(o.corner_position_mm)}",
        f"the shooting pose (the camera at process.working_distance_mm = {wd:g} before T's point {_vec(np.round(aim))})",
        "place the opening within the robot's working range (layout.robot.min_reach_mm to reach_mm from its "
        "reach_centre_mm), or correct [layout.robot] to the robot fitted",
        shoot,
    )  # fmt: skip
    return [first, *wall_reading_poses(config, shoot), *install_poses(config)]


def reach_problem(config: CellConfig) -> str | None:
    """Why the robot of ``[layout.robot]`` cannot reach a pose the window needs (the first, the others counted), or None."""
    robot = config.layout.robot
    found = [(p, why) for p in nominal_poses(config) if (why := robot.reach_problem(p.T_B_H, p.what)) is not None]
    if not found:
        return None
    pose, why = found[0]
    more = f" ({len(found) - 1} more of its poses are out of the robot's reach too)" if len(found) > 1 else ""
    return f"{pose.setting}: {why}: {pose.fix}{more}"

