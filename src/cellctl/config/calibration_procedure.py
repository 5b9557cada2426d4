"""How the cell is calibrated and taught: targets, pose plans, refusal limits, device timeouts.

Positions on the car-body wall are in the nominal workpiece frame T0 (x right, y down from the
opening's upper-right corner, z into the wall; the opening is x in [-width, 0], y in [0, height]).
"""

from __future__ import annotations

from typing import Literal, get_args

import numpy as np
from pydantic import Field, model_validator

from cellctl.config.types import Finite, StrictModel, Vec2, Vec3


class BoardConfig(StrictModel):
    """A printed checkerboard: (columns, rows) of inner corners, one odd and one even."""

    inner_corners: tuple[int, int] = (11, 8)
    square_mm: Finite = Field(10.0, gt=0)
    border_mm: Finite = Field(10.0, ge=0)

    @model_validator(mode="after")
    def _asymmetric(self) -> "BoardConfig":
        cols, rows = self.inner_corners
        if cols < 3 or rows < 3:
            raise ValueError(f"inner_corners must both be at least 3, got {self.inner_corners}")
        if (cols + rows) % 2 == 0:
            raise ValueError(
                f"inner_corners {self.inner_corners}: use one odd and one even number, otherwise the board looks "
                "the same turned by 180 deg and its pose is ambiguous"
            )
        return self


class CameraCalibrationConfig(StrictModel):
    """Intrinsics by Zhang's method from views of the board stuck on the wall."""

    board: BoardConfig = BoardConfig()
    board_on_wall_mm: Vec2 = (100.0, 200.0)  # the board's first inner corner on the wall, in T0
    n_views: int = Field(12, ge=3, le=200)
    distance_mm: tuple[Finite, Finite] = (400.0, 470.0)  # camera to board centre
    tilt_deg: tuple[Finite, Finite] = (12.0, 35.0)
    spin_deg: Finite = Field(35.0, ge=0, le=180)
    # Keep the board (with its border) this far inside the image in every planned view: px of a 2048 px wide image,
    # scaled by layout.camera.width_px / 2048 (7.5 px on a 512 px camera binned 4 x 4).
    margin_px: Finite = Field(30.0, ge=0)
    refine: Literal["subpix", "sb"] = "subpix"
    # k3 held at 0 (OpenCV's CALIB_FIX_K3): the board fills the middle of the view, so a free k3 trades
    # off against k2 and bends lines beyond the board's reach (0.04 deg along the door window's top edge
    # near the image's border, issue 21); a fixed industrial lens needs k1, k2 only (the twin's k3 = 0.04
    # moves a pixel at the image's corner by 0.02 px). Free it only for a wide-angle lens.
    fix_k3: bool = True
    min_views: int = Field(8, ge=3)
    max_rms_px: Finite = Field(0.5, gt=0)
    reject_factor: Finite = Field(3.0, gt=1)  # a view above this times the median per-view RMS ...
    reject_floor_px: Finite = Field(0.1, gt=0)  # ... and above this absolute RMS is rejected
    # Refused when the board's normal scatters less than this (RMS angle from its mean over the views): parallel
    # views leave the focal length unobservable (Zhang 3.1). The planned views (tilts 12-35 deg) scatter 15-25 deg.
    min_tilt_spread_deg: Finite = Field(5.0, ge=0, le=60)
    # Refused when OpenCV's std of fx or fy exceeds this share of it (1e-3: about 0.4 mm of depth at 430 mm).
    max_focal_std_ratio: Finite = Field(1e-3, gt=0)
    # Refused when the single views' focal lengths (the other intrinsics held) scatter by more than this many of
    # their own standard deviations (RMS): views taken at two focus or zoom settings. Consistent views give about 1.
    max_view_focal_sigma: Finite = Field(3.0, gt=0)
    # ... and by more than this share of fx (weighted RMS): a real lens's model error may scatter the views beyond
    # their corner noise alone; a spread below 5e-4 (0.2 mm of depth at 430 mm) is never refused.
    min_view_focal_spread: Finite = Field(5e-4, ge=0)


HandEyeMethod = Literal["tsai", "opencv_tsai", "opencv_park", "opencv_horaud", "opencv_andreff", "opencv_daniilidis"]
HAND_EYE_METHODS: tuple[HandEyeMethod, ...] = get_args(HandEyeMethod)


class HandEyeCalibrationConfig(StrictModel):
    """Hand-eye T_H_C from the same kind of board views, with the robot's reported poses."""

    method: HandEyeMethod = "tsai"
    min_views: int = Field(6, ge=3)
    recommended_views: int = Field(10, ge=3)
    min_pair_angle_deg: Finite = Field(5.0, ge=0, le=45)
    min_max_pair_angle_deg: Finite = Field(15.0, ge=0, le=180)
    min_axis_spread: Finite = Field(0.05, ge=0, le=1)
    warn_axis_spread: Finite = Field(0.15, ge=0, le=1)  # below this the result carries a warning
    max_translation_disagreement_mm: Finite = Field(1.0, gt=0)  # between methods, before it is refused
    max_rotation_disagreement_deg: Finite = Field(0.1, gt=0)


# The fewest readings calibrate_laser accepts when not told otherwise, and the floor of min_poses.
LASER_MIN_POSES = 12


class LaserCalibrationConfig(StrictModel):
    """r and l from a flat patch of the car-body wall seen from many wrist orientations.

    The wrist centre stands at offsets along the wall normal from ``wrist_depth_range_mm[0]`` to
    ``[1]`` in steps of ``wrist_depth_step_mm`` (one arm stand each; see
    cellctl.calibration.poses.plan_laser_poses); each pose picks the stand that puts its distance
    where the plan wants it. The twin checks every pose for reach and for a spot on plain wall,
    not for collisions: on a real cell, check the largest tilt and spin against the gripper's
    clearance to the car body before the first run (and narrow them if needed; fewer directions
    make l less certain, and the calibration reports by how much).
    """

    aim_mm: Vec2 = (900.0, 750.0)  # where the untilted beam meets the wall, in T0 (plain wall around it)
    keep_off_opening_mm: Finite = Field(40.0, ge=0)
    n_poses: int = Field(480, ge=3, le=5000)
    standoff_mm: Finite = Field(350.0, gt=0)
    wrist_depth_range_mm: tuple[Finite, Finite] = (-300.0, 160.0)  # positive: away from the wall
    wrist_depth_step_mm: Finite = Field(20.0, gt=0)
    tilt_deg: tuple[Finite, Finite] = (20.0, 45.0)
    spin_deg: Finite = Field(90.0, ge=0, le=180)
    range_margin_mm: Finite = Field(6.0, ge=0)  # keep nominal distances this far inside the sensor's range
    wrist_in_flange_mm: Vec3 = (0.0, 0.0, -250.0)  # the wrist centre (axis 5) in the flange frame
    linearity_terms: int = Field(5, ge=0, le=8)  # Legendre terms 2.. of the sensor's linearity curve
    min_poses: int = Field(100, ge=LASER_MIN_POSES)  # fewer rarely pin r and l within max_r_sigma_mm / max_l_sigma_deg
    min_direction_spread_deg: Finite = Field(4.0, ge=0)
    max_rms_mm: Finite = Field(0.1, gt=0)
    max_r_sigma_mm: Finite = Field(0.3, gt=0)
    max_l_sigma_deg: Finite = Field(0.05, gt=0)

    @model_validator(mode="after")
    def _stands(self) -> "LaserCalibrationConfig":
        lo, hi = self.wrist_depth_range_mm
        if hi < lo:
            raise ValueError(f"wrist_depth_range_mm {self.wrist_depth_range_mm}: give (nearest, farthest), the first not above the second")
        if (hi - lo) / self.wrist_depth_step_mm > 200:
            raise ValueError(
                f"wrist_depth_step_mm {self.wrist_depth_step_mm:g} makes {int((hi - lo) / self.wrist_depth_step_mm) + 1} arm stands "
                "over wrist_depth_range_mm; use a step of at least 1/200 of the range"
            )
        lo_t, hi_t = self.tilt_deg
        if not 0 <= lo_t <= hi_t <= 80:
            raise ValueError(f"tilt_deg {self.tilt_deg}: give (smallest, largest) between 0 and 80 deg")
        return self

    def wrist_depths_mm(self) -> tuple[float, ...]:
        """The arm stands: wrist-centre offsets along the wall normal."""
        lo, hi = self.wrist_depth_range_mm
        count = int(np.floor((hi - lo) / self.wrist_depth_step_mm + 1e-9)) + 1
        return tuple(float(lo + k * self.wrist_depth_step_mm) for k in range(count))


class NinePointConfig(StrictModel):
    """Pixel scale (eq. 15) and the nine-point map at the taught shooting pose C_Pos_0.

    The map comes from the robot moving the camera to a 3 x 3 grid of offsets in the wall plane
    (``step_mm`` apart, along T0's axes) while the corner detector measures the window corner.
    """

    step_mm: Finite = Field(15.0, gt=0, le=50)
    max_rms_mm: Finite = Field(0.1, gt=0)
    scale_board: BoardConfig = BoardConfig()
    scale_board_on_wall_mm: Vec2 = (-50.0, -35.0)  # first inner corner of the scale board, in T0 from the shot's aim


class TeachConfig(StrictModel):
    """Teaching (paper 4.3 step 1).

    The install pose g_Pos_0 is taught by guiding the glass into the opening by hand
    ``hand_guided_installs`` times and taking the mean of the poses the controller reports: the
    operator's random error shrinks as 1/sqrt(n), and the spread between the installs, reported
    with the result, shows how well they agreed. Installs further than ``max_install_spread_mm``
    / ``max_install_spread_deg`` from their mean are refused (guide again).
    """

    hand_guided_installs: int = Field(3, ge=1, le=20)
    max_install_spread_mm: Finite = Field(0.5, gt=0)
    max_install_spread_deg: Finite = Field(0.2, gt=0)


class VerifyCalibrationConfig(StrictModel):
    """``cellctl calibrate verify``: has the camera or the laser moved on the fixture since they were calibrated?

    The check revisits some of the very poses the stored calibrations were collected at
    (``views`` board views spread over each of the camera's and the hand-eye's datasets, and
    ``laser_poses_per_stand`` poses at ``laser_stands`` arm stands of the laser dataset's) and
    estimates how far camera and laser moved from the change between the stored and the new
    data at the same poses, free of the robot's accuracy errors there (the same in both). A drift beyond the limits raises the drift alarm. ``every_cycles`` /
    ``every_hours`` (0: never) raise a reminder alarm when a check is due. Each check writes a
    dataset into ``<calibration directory>/datasets`` (about 47 MiB with a 2048 x 2048 px camera);
    after it, the oldest check datasets beyond the newest ``keep_datasets`` are removed (never one
    a calibration-set version names; the calibrations' own datasets are always kept).
    """

    views: int = Field(12, ge=4, le=100)
    laser_stands: int = Field(6, ge=0, le=200)  # 0: check the hand-eye only
    laser_poses_per_stand: int = Field(12, ge=3, le=100)
    max_hand_eye_mm: Finite = Field(0.25, gt=0)
    max_hand_eye_deg: Finite = Field(0.025, gt=0)
    max_laser_r_mm: Finite = Field(1.0, gt=0)
    max_laser_l_deg: Finite = Field(0.15, gt=0)
    every_cycles: int = Field(0, ge=0)
    every_hours: Finite = Field(0.0, ge=0)
    keep_datasets: int = 10  # the newest check datasets kept (the one just written among them)

    @model_validator(mode="after")
    def _keep(self) -> "VerifyCalibrationConfig":
        if self.keep_datasets < 1:
            raise ValueError(
                f"keep_datasets {self.keep_datasets}: give at least 1 (the check just written is always kept); "
                "each check's dataset takes about 47 MiB in <calibration directory>/datasets"
            )
        return self


# ISO 10218-1 reduced speed: what a robot may do with people near it under supervision.
REDUCED_SPEED_MM_S = 250.0


class MotionSettings(StrictModel):
    """Speeds and timeouts of a procedure's moves and reads.

    Every move runs at ``speed_mm_s`` / ``speed_deg_s`` at most; the TCP speed may not exceed the
    reduced speed of ISO 10218-1 (250 mm/s), since the engineer works beside the cell while the
    job runs.
    """

    move_timeout_s: Finite = Field(60.0, gt=0)
    read_timeout_s: Finite = Field(5.0, gt=0)
    grab_timeout_s: Finite = Field(10.0, gt=0)
    speed_mm_s: Finite = Field(250.0, gt=0, le=REDUCED_SPEED_MM_S)
    speed_deg_s: Finite = Field(30.0, gt=0, le=90)


class CalibrationProcedureConfig(MotionSettings):
    """Everything the calibration and teaching procedures read (the store folder and the parts'
    validity are the ``calibration`` section's ``directory`` and ``max_age_days``); the motion
    settings stand at the top of the section.
    """

    camera: CameraCalibrationConfig = CameraCalibrationConfig()
    hand_eye: HandEyeCalibrationConfig = HandEyeCalibrationConfig()
    laser: LaserCalibrationConfig = LaserCalibrationConfig()
    nine_point: NinePointConfig = NinePointConfig()
    teach: TeachConfig = TeachConfig()
    verify: VerifyCalibrationConfig = VerifyCalibrationConfig()
