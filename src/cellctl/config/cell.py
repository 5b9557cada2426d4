"""The cell's process settings: working distance, tolerances, alignment spots and gates."""

from __future__ import annotations

from pydantic import Field, model_validator

from cellctl.config.inspection import InspectionConfig
from cellctl.config.spc import SpcConfig
from cellctl.config.types import Finite, StrictModel, Vec2


class ToleranceConfig(StrictModel):
    """Install tolerance (paper: +-0.5 mm, +-1 deg)."""

    position_mm: Finite = Field(0.5, gt=0)
    orientation_deg: Finite = Field(1.0, gt=0)


class AlignConfig(StrictModel):
    """Laser alignment (paper section 3).

    ``spots_mm`` are where the laser should hit the wall, in the taught workpiece frame T0
    (x right, y down from the upper-right corner; the opening is x < 0, 0 < y). Keep them on the
    wall, off the opening, and spread in two directions.
    """

    spots_mm: tuple[Vec2, ...] = (
        (-1500.0, -60.0),
        (-500.0, -60.0),
        (60.0, 300.0),
        (60.0, 1200.0),
        (-1000.0, 1560.0),
        (-2060.0, 750.0),
    )
    laser_standoff_mm: Finite = Field(350.0, gt=0)
    laser_range_mm: Vec2 = (250.0, 450.0)  # the sensor head's measuring range (LK-G500); readings outside are refused
    max_rms_mm: Finite = Field(0.2, gt=0)
    inlier_threshold_mm: Finite = Field(0.5, gt=0)
    min_collinearity: Finite = Field(1e-3, gt=0, lt=1)

    @model_validator(mode="after")
    def _standoff_in_range(self) -> "AlignConfig":
        lo, hi = self.laser_range_mm
        if not 0 < lo < hi:
            raise ValueError(f"laser_range_mm must be [min, max] with 0 < min < max, got {list(self.laser_range_mm)}")
        if not lo < self.laser_standoff_mm < hi:
            raise ValueError(f"laser_standoff_mm ({self.laser_standoff_mm:g}) must lie inside laser_range_mm {list(self.laser_range_mm)}")
        return self

    @model_validator(mode="after")
    def _enough_spots(self) -> "AlignConfig":
        if len(self.spots_mm) < 3:
            raise ValueError(f"spots_mm has {len(self.spots_mm)} spots; the plane needs at least 3")
        return self


class MotionConfig(StrictModel):
    """Speeds and timeouts of the cycle's robot moves."""

    travel_speed_mm_s: Finite = Field(500.0, gt=0, le=7000)  # between spots, to the shooting pose
    fine_speed_mm_s: Finite = Field(50.0, gt=0, le=1000)  # the last approach into the opening
    speed_deg_s: Finite = Field(30.0, gt=0, le=500)
    approach_mm: Finite = Field(100.0, ge=0)  # stand-off in front of the install pose
    move_timeout_s: Finite = Field(60.0, gt=0)
    read_timeout_s: Finite = Field(2.0, gt=0)  # laser reading, pose read-back
    grab_timeout_s: Finite = Field(5.0, gt=0)


class VerifyConfig(StrictModel):
    """Verification shots: re-shoot at the corrected shooting pose until the residual is small.

    Each verification shot, taken after a fresh move, is an independent estimate of the workpiece
    frame whose error is mostly the robot's repeatability at that move; the cell installs on the
    mean of the verification estimates. ``residual_mm``/``residual_deg`` should sit above the
    robot's repeatability (about 3 sigma), or the loop chases noise.
    """

    # The first shot only aims the verification shots, so its corner may be near the image border
    # (a car body far off its nominal posture) with short straight edges: looser gates for it.
    first_shot_sigma_px: Finite = Field(0.5, gt=0)
    first_shot_min_edge_points: int = Field(30, ge=10)
    min_shots: int = Field(2, ge=1, le=10)  # verification shots averaged at least
    max_shots: int = Field(4, ge=1, le=10)  # give up (Hold) when still not converged after these
    residual_mm: Finite = Field(0.1, gt=0)
    residual_deg: Finite = Field(0.05, gt=0)

    @model_validator(mode="after")
    def _order(self) -> "VerifyConfig":
        if self.min_shots > self.max_shots:
            raise ValueError(f"min_shots ({self.min_shots}) must not exceed max_shots ({self.max_shots})")
        return self


class LimitsConfig(StrictModel):
    """How far a correction may move the robot from its taught pose.

    Keep them above what the car body's posture range can ask for: +-20 mm and +-2 deg about each
    axis move the install pose (the flange ~1.25 m from the corner) by up to ~110 mm and 3.5 deg.
    """

    max_correction_mm: Finite = Field(150.0, gt=0)
    max_correction_deg: Finite = Field(8.0, gt=0, le=45)
    max_verify_step_mm: Finite = Field(5.0, gt=0)  # one verification shot's correction
    max_verify_step_deg: Finite = Field(0.5, gt=0)


class Recipe(StrictModel):
    """A workpiece type the cell installs: its PLC number and the name records and the API use."""

    id: int = Field(ge=1, le=65535)
    name: str = Field(min_length=1, max_length=64, pattern=r"^[a-z0-9][a-z0-9_.-]*$")
    description: str = ""


class ProcessConfig(StrictModel):
    """What the cell does each cycle."""

    working_distance_mm: Finite = Field(400.0, gt=0)
    tolerance: ToleranceConfig = ToleranceConfig()
    align: AlignConfig = AlignConfig()
    motion: MotionConfig = MotionConfig()
    verify: VerifyConfig = VerifyConfig()
    limits: LimitsConfig = LimitsConfig()
    inspect: InspectionConfig = InspectionConfig()
    spc: SpcConfig = SpcConfig()
    recipes: tuple[Recipe, ...] = (Recipe(id=1, name="side-window", description="2000 x 1500 mm side-window glass"),)

    @model_validator(mode="after")
    def _unique_recipes(self) -> "ProcessConfig":
        if not self.recipes:
            raise ValueError("recipes: give at least one recipe (id and name)")
        for what in ("id", "name"):
            values = [getattr(r, what) for r in self.recipes]
            if len(set(values)) != len(values):
                raise ValueError(f"recipes: each recipe needs its own {what}, got {values}")
        return self

    def recipe_names(self) -> dict[int, str]:
        """PLC recipe number -> recipe name."""
        return {r.id: r.name for r in self.recipes}
