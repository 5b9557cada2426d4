"""The simulated cell (digital twin): world, robot, sensors and their error sources."""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from cellctl.config.mounting import CameraIntrinsics, HandEye, LaserMount
from cellctl.config.render import RenderConfig
from cellctl.config.types import Finite, StrictModel, UnitVec3, Vec3, as_array
from cellctl.geometry.pose import Pose, make_pose


class WorldConfig(StrictModel):
    """The car-body wall with its window opening, and how the car body's posture varies.

    The workpiece frame T sits at the opening's upper-right corner as the camera sees it: the
    point where the top and right straight edges would meet. Its z axis points into the wall
    (``wall_normal``), its y axis points down along the wall (against ``up``), and x = y cross z
    points right, so T's axes line up with the image's u, v and optical axis at the shooting pose.
    The opening occupies x in [-width, 0], y in [0, height] of T, with rounded corners.
    """

    corner_position_mm: Vec3 = (1700.0, -1000.0, 1800.0)
    wall_normal: UnitVec3 = (1.0, 0.0, 0.0)
    up: UnitVec3 = (0.0, 0.0, 1.0)
    opening_width_mm: Finite = Field(2000.0, gt=0)
    opening_height_mm: Finite = Field(1500.0, gt=0)
    corner_radius_mm: Finite = Field(30.0, ge=0)
    posture_translation_mm: Vec3 = (20.0, 20.0, 20.0)
    posture_rotation_deg: Vec3 = (2.0, 2.0, 2.0)

    @model_validator(mode="after")
    def _geometry(self) -> "WorldConfig":
        if abs(float(np.dot(self.wall_normal, self.up))) > 1e-6:
            raise ValueError("up must lie in the wall: it has to be perpendicular to wall_normal")
        if 2 * self.corner_radius_mm > min(self.opening_width_mm, self.opening_height_mm):
            raise ValueError("corner_radius_mm is larger than half the opening's smaller side")
        if any(v < 0 for v in (*self.posture_translation_mm, *self.posture_rotation_deg)):
            raise ValueError("posture ranges are half-widths and must not be negative")
        return self

    def T_B_T_nominal(self) -> Pose:
        """The nominal workpiece frame at the upper-right corner, in the robot base frame."""
        z = as_array(self.wall_normal)
        y = -as_array(self.up)
        x = np.cross(y, z)
        return make_pose(np.column_stack([x, y, z]), self.corner_position_mm)


class RobotSimConfig(StrictModel):
    """IRB 7600-325 as the twin models it."""

    reach_mm: Finite = Field(3100.0, gt=0)
    repeatability_mm: Finite = Field(0.1, ge=0)
    absolute_accuracy_mm: Finite = Field(0.5, ge=0)
    max_speed_mm_s: Finite = Field(1000.0, gt=0)
    acceleration_mm_s2: Finite = Field(2000.0, gt=0)


class LaserSimConfig(LaserMount):
    """LK-G500 on the fixture: mounting (eq. 19) and error sources."""

    linearity_fraction_fs: Finite = Field(0.0002, ge=0)  # +-0.02 % of full scale (paper)
    noise_mm: Finite = Field(0.002, ge=0)  # repeatability of the LK-G500 head, one sigma


class CameraSimConfig(StrictModel):
    """The camera (eq. 17) and its mounting (eq. 18)."""

    intrinsics: CameraIntrinsics = CameraIntrinsics()
    hand_eye: HandEye = HandEye()
    render: RenderConfig = RenderConfig()


class GlassConfig(StrictModel):
    """The glass on the gripper: its upper-right corner frame G in the flange frame H.

    G is defined like T (x right, y down, z into the wall when installed); a correct install puts
    G onto T. The default holds the glass with its plane parallel to the flange plane.
    """

    width_mm: Finite = Field(2000.0, gt=0)
    height_mm: Finite = Field(1500.0, gt=0)
    corner_in_flange_mm: Vec3 = (1000.0, -750.0, 120.0)

    def T_H_G(self) -> Pose:
        """The glass corner frame in the flange frame."""
        return make_pose(np.eye(3), self.corner_in_flange_mm)


class SimConfig(StrictModel):
    """Everything the twin needs; deterministic for a seed."""

    seed: int = 1
    world: WorldConfig = WorldConfig()
    robot: RobotSimConfig = RobotSimConfig()
    laser: LaserSimConfig = LaserSimConfig()
    camera: CameraSimConfig = CameraSimConfig()
    glass: GlassConfig = GlassConfig()
