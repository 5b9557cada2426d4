"""The cell's nominal layout: what the drawings say, used by plans in both modes.

Calibration and teaching plans need to know roughly where things are before anything has been
measured: where the car-body wall and the opening's upper-right corner stand in the robot base
frame, how the camera and the laser sit on the fixture (the CAD mountings), what the lens is
(the data sheet), and how far the robot reaches. None of this is the truth: the calibrations
measure it. In the simulated cell the twin's car body stands at this nominal opening (plus its
random posture); its true mountings and lens are ``[sim]``'s.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from pydantic import Field, model_validator

from cellctl.config.mounting import CameraIntrinsics, HandEye, LaserMount
from cellctl.config.types import Finite, StrictModel, UnitVec3, Vec3, as_array
from cellctl.geometry.motion import path_timing
from cellctl.geometry.pose import Pose, make_pose


def opening_problem(wall_normal: tuple[float, float, float], up: tuple[float, float, float], width_mm: float,
                    height_mm: float, corner_radius_mm: float) -> str | None:  # fmt: skip
    """Why an opening's geometry cannot be (up not in the wall, radius too large), or None."""
    if abs(float(np.dot(wall_normal, up))) > 1e-6:
        return "up must lie in the wall: it has to be perpendicular to wall_normal"
    if 2 * corner_radius_mm > min(width_mm, height_mm):
        return "corner_radius_mm is larger than half the opening's smaller side"
    return None


def workpiece_frame(corner_position_mm: ArrayLike, wall_normal: ArrayLike, up: ArrayLike) -> Pose:
    """T at the opening's upper-right corner: z into the wall, y down along it (against ``up``), x = y cross z."""
    z = np.asarray(wall_normal, dtype=float)
    y = -np.asarray(up, dtype=float)
    return make_pose(np.column_stack([np.cross(y, z), y, z]), corner_position_mm)


class OpeningLayout(StrictModel):
    """The window opening in the car-body wall where the car body nominally stands.

    The workpiece frame T sits at the opening's upper-right corner as the camera sees it: the
    point where the top and right straight edges would meet. Its z axis points into the wall
    (``wall_normal``), its y axis points down along the wall (against ``up``), and x = y cross z
    points right, so T's axes line up with the image's u, v and optical axis at the shooting pose.
    The opening occupies x in [-width, 0], y in [0, height] of T, with rounded corners.
    """

    corner_position_mm: Vec3 = (1700.0, -1000.0, 1800.0)
    wall_normal: UnitVec3 = (1.0, 0.0, 0.0)
    up: UnitVec3 = (0.0, 0.0, 1.0)
    width_mm: Finite = Field(2000.0, gt=0)
    height_mm: Finite = Field(1500.0, gt=0)
    corner_radius_mm: Finite = Field(30.0, ge=0)

    @model_validator(mode="after")
    def _geometry(self) -> "OpeningLayout":
        problem = opening_problem(self.wall_normal, self.up, self.width_mm, self.height_mm, self.corner_radius_mm)
        if problem is not None:
            raise ValueError(problem)
        return self

    def T_B_T_nominal(self) -> Pose:
        """The nominal workpiece frame at the upper-right corner, in the robot base frame."""
        return workpiece_frame(self.corner_position_mm, self.wall_normal, self.up)

    def on_wall(self, xy_mm: ArrayLike, margin_mm: float) -> bool:
        """True if the point (x, y in T, mm) lies on the wall at least ``margin_mm`` off the opening."""
        x, y = (float(v) for v in np.asarray(xy_mm, dtype=float)[:2])
        m = float(margin_mm)
        return x > m or y < -m or x < -self.width_mm - m or y > self.height_mm + m


def check_reach_order(min_reach_mm: float, reach_mm: float) -> None:
    """A robot's working range needs ``min_reach_mm`` below ``reach_mm`` (ValueError if not)."""
    if min_reach_mm >= reach_mm:
        raise ValueError(f"min_reach_mm ({min_reach_mm:g}) must be below reach_mm ({reach_mm:g})")


def wrist_centre_of(T_B_H: ArrayLike, wrist_to_flange_mm: float) -> np.ndarray:
    """The wrist centre (mm, base frame) of flange pose T_B_H: its origin moved back along its z axis."""
    M = np.asarray(T_B_H, dtype=float)
    return M[:3, 3] - wrist_to_flange_mm * M[:3, 2]


def wrist_reach_mm(T_B_H: ArrayLike, wrist_to_flange_mm: float, reach_centre_mm: Vec3) -> float:
    """The distance (mm) of flange pose T_B_H's wrist centre from ``reach_centre_mm``."""
    return float(np.linalg.norm(wrist_centre_of(T_B_H, wrist_to_flange_mm) - as_array(reach_centre_mm)))


class RobotEnvelope(StrictModel):
    """The robot's working range and motion limits as its data sheet gives them (IRB 7600-325).

    The wrist centre (axis 5: the flange origin moved back ``wrist_to_flange_mm`` along the
    flange's z axis) must lie between ``min_reach_mm`` and ``reach_mm`` from ``reach_centre_mm``
    (the axis-1 centre line at the height of axis 2, from where ABB quotes the 3.1 m reach).
    Plans check every pose against it before the robot moves; the controller has the last word
    (it refuses a target it cannot reach, and the procedure drops that pose with the reason).
    Speeds, accelerations and the fine-point settling time give a plan's estimated robot time.
    """

    reach_mm: Finite = Field(3100.0, gt=0)
    min_reach_mm: Finite = Field(500.0, ge=0)
    reach_centre_mm: Vec3 = (0.0, 0.0, 780.0)
    wrist_to_flange_mm: Finite = Field(250.0, ge=0)
    max_speed_mm_s: Finite = Field(1000.0, gt=0, le=7000.0)
    acceleration_mm_s2: Finite = Field(2000.0, gt=0)
    max_speed_deg_s: Finite = Field(60.0, gt=0, le=1000.0)
    acceleration_deg_s2: Finite = Field(120.0, gt=0)
    settle_time_s: Finite = Field(0.15, ge=0, le=10.0)

    @model_validator(mode="after")
    def _order(self) -> "RobotEnvelope":
        check_reach_order(self.min_reach_mm, self.reach_mm)
        return self

    def wrist_centre(self, T_B_H: ArrayLike) -> np.ndarray:
        """The wrist centre of flange pose T_B_H (mm, base frame)."""
        return wrist_centre_of(T_B_H, self.wrist_to_flange_mm)

    def reach_distance(self, T_B_H: ArrayLike) -> float:
        """The wrist centre's distance (mm) from the reach centre."""
        return wrist_reach_mm(T_B_H, self.wrist_to_flange_mm, self.reach_centre_mm)

    def reach_problem(self, T_B_H: ArrayLike, what: str = "target") -> str | None:
        """Why flange pose T_B_H is outside the working range, or None if it is inside."""
        dist = self.reach_distance(T_B_H)
        if dist > self.reach_mm:
            return (
                f"{what} out of reach: its wrist centre is {dist:.0f} mm from the robot's reach centre, "
                f"beyond the {self.reach_mm:g} mm reach; bring the car body or the target closer"
            )
        if dist < self.min_reach_mm:
            return (
                f"{what} too close to the robot: its wrist centre is {dist:.0f} mm from the reach centre, "
                f"inside the {self.min_reach_mm:g} mm the arm cannot fold into"
            )
        return None

    def move_time_s(self, T_from: ArrayLike, T_to: ArrayLike, speed_mm_s: float, speed_deg_s: float) -> float:
        """Seconds a move from ``T_from`` to ``T_to`` takes at the given speeds (capped at the robot's), settling included."""
        return path_timing(
            T_from, T_to,
            speed_mm_s=min(float(speed_mm_s), self.max_speed_mm_s), acceleration_mm_s2=self.acceleration_mm_s2,
            speed_rad_s=float(np.deg2rad(min(float(speed_deg_s), self.max_speed_deg_s))),
            acceleration_rad_s2=float(np.deg2rad(self.acceleration_deg_s2)), settle_s=self.settle_time_s,
        ).duration_s  # fmt: skip


# The paper's cell as drawn: a 35 mm lens on 6.67 um pixels (no distortion known), the camera and
# the LK-G500 head on the fixture to the drawing's 1 mm and 0.01.
DATASHEET_LENS = CameraIntrinsics(fx=5250.0, fy=5250.0, cx=1024.0, cy=1024.0, k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0)
DRAWN_CAMERA_MOUNT = HandEye(
    translation_mm=(-55.0, -75.0, 103.0),
    rotation_rows=((0.01, -0.04, -1.0), (1.0, 0.01, 0.01), (0.01, -1.0, 0.04)),
    optical_axis_fix="flip_about_x",
)
DRAWN_LASER_MOUNT = LaserMount(origin_mm=(44.0, -40.0, 90.0), direction=(0.99776, 0.05987, 0.02993))


class LayoutConfig(StrictModel):
    """The cell as drawn: opening, lens, camera and laser mountings, robot envelope."""

    opening: OpeningLayout = OpeningLayout()
    camera: CameraIntrinsics = DATASHEET_LENS  # the lens as the data sheet gives it (plans only)
    camera_mount: HandEye = DRAWN_CAMERA_MOUNT  # T_H_C as the fixture drawing gives it
    laser_mount: LaserMount = DRAWN_LASER_MOUNT  # r, l as the fixture drawing gives them, and the head's range
    robot: RobotEnvelope = RobotEnvelope()


_CORNER_NAMES = ("upper-right", "upper-left", "lower-left", "lower-right")  # T's origin, then x = -width, y = height


def opening_placement_problem(layout: LayoutConfig) -> str | None:
    """Why ``layout.opening`` cannot stand before the robot of ``layout.robot`` (None: it can).

    Its ``wall_normal`` must point into the wall, away from the robot's reach centre; and each of
    its corners must lie where the laser can read it: within the robot's reach plus the laser's
    range and its mounting's distance from the wrist centre (mm, robot base frame).
    """
    o, robot = layout.opening, layout.robot
    n, corner = as_array(o.wall_normal), as_array(o.corner_position_mm)
    centre = as_array(robot.reach_centre_mm)
    away = float(n @ (corner - centre))
    if away <= 0.0:
        return (f"layout.opening.wall_normal = {_vec(o.wall_normal)} points back at the robot: the opening's corner "
                f"(corner_position_mm = {_vec(o.corner_position_mm)}) lies {_vec(corner - centre)} mm from "
                f"layout.robot.reach_centre_mm, and the normal must point into the wall, away from the robot "
                f"(their dot product is {away:.0f} mm); flip its sign (wall_normal = {_vec(-n)})")  # fmt: skip
    T = o.T_B_T_nominal()
    xy = np.array([[0.0, 0.0], [-o.width_mm, 0.0], [-o.width_mm, o.height_mm], [0.0, o.height_mm]])
    pts = T[:3, :3] @ np.column_stack([xy, np.zeros(4)]).T + T[:3, 3:4]
    dist = np.linalg.norm(pts.T - centre, axis=1)
    k = int(np.argmax(dist))
    mount = float(np.linalg.norm(layout.laser_mount.r + np.array([0.0, 0.0, robot.wrist_to_flange_mm])))
    limit = robot.reach_mm + layout.laser_mount.range_max_mm + mount
    if dist[k] > limit:
        return (f"layout.opening.up = {_vec(o.up)}, corner_position_mm = {_vec(o.corner_position_mm)}, width_mm = "
                f"{o.width_mm:g} and height_mm = {o.height_mm:g} put the opening's {_CORNER_NAMES[k]} corner at "
                f"{_vec(pts[:, k])} mm in the robot base, {dist[k]:.0f} mm from layout.robot.reach_centre_mm: beyond the "
                f"robot's reach (layout.robot.reach_mm = {robot.reach_mm:g}) plus the laser's range "
                f"({layout.laser_mount.range_max_mm:g}) and its mounting ({mount:.0f} mm from the wrist centre), so no "
                "pose reads the wall there; check up's sign (it points up along the wall, in the robot base frame), "
                "those figures (mm) and layout.robot.reach_mm")  # fmt: skip
    return None


def _vec(v: ArrayLike) -> str:
    return "[" + ", ".join(f"{float(x) + 0.0:g}" for x in np.asarray(v, dtype=float)) + "]"  # + 0.0: no -0


# The twin's car body stands at the layout's opening and its robot reaches as far as the layout's:
# these fields of [sim.world] and [sim.robot] are filled from [layout] (never set there).
TWIN_FIELDS_FROM_LAYOUT: dict[tuple[str, str], tuple[str, str]] = {
    **{("world", name): ("opening", name) for name in OpeningLayout.model_fields},
    **{("robot", name): ("robot", name) for name in RobotEnvelope.model_fields},
}
