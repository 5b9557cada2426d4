"""The simulated cell (digital twin): world, robot, sensors and their error sources."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from cellctl.config.layout import OpeningLayout, RobotEnvelope, check_reach_order
from cellctl.config.mounting import CameraIntrinsics, HandEye, LaserMount
from cellctl.config.render import RenderConfig
from cellctl.config.surface import Range
from cellctl.config.types import Finite, StrictModel, Vec3
from cellctl.geometry.pose import Pose, pose_from_xyz_fixed_deg


class WorldConfig(OpeningLayout):
    """The twin's car-body wall with its window opening, and how the car body's posture varies.

    The car body stands at the cell's nominal opening (the fields of :class:`OpeningLayout`, whose
    docstring defines the workpiece frame T): in a cell configuration they are filled from
    ``[layout.opening]`` and only the posture is the twin's own. Each cycle
    the car body is placed at a random posture about the nominal one.
    """

    posture_translation_mm: Vec3 = (20.0, 20.0, 20.0)
    posture_rotation_deg: Vec3 = (2.0, 2.0, 2.0)
    # Where the posture's rotation turns about: "corner" (the workpiece frame T, the paper's posture)
    # or "opening_centre". About the centre, +-2 deg swing the corner by up to +-44 mm more, so with
    # the 156 mm view at 400 mm a straight edge can leave the image; such cycles are refused.
    posture_pivot: Literal["corner", "opening_centre"] = "corner"

    @model_validator(mode="after")
    def _posture(self) -> "WorldConfig":
        if any(v < 0 for v in (*self.posture_translation_mm, *self.posture_rotation_deg)):
            raise ValueError("posture ranges are half-widths and must not be negative")
        return self


class RobotSimConfig(RobotEnvelope):
    """ABB IRB 7600-325 as the twin models it.

    Error sources (each one off when its magnitude is 0):

    - absolute accuracy: a smooth, pose-dependent deformation fixed per robot (seeded), bounded
      by ``absolute_accuracy_mm`` in position and ``absolute_accuracy_deg`` in orientation, that
      changes little over ``accuracy_wavelength_mm`` (an uncalibrated robot: up to about 0.5 mm).
    - repeatability: ISO 9283 pose repeatability RP (``repeatability_mm``, paper: 0.1 mm) and
      orientation repeatability (``repeatability_orientation_deg``, the ISO 9283 +-3 S per angle).
    - path deviation at speed (zero at rest): the arm lags the reported path by ``path_lag_s`` and
      deviates sideways by ``path_sideways_s`` times the TCP speed; defaults give 0.15 / 0.05 mm at
      500 mm/s on a straight line (Slamani et al. 2012: about 0.25 mm radial at 700 mm/s on a small
      circle, IRB 1600).
    - position feedback (EGM): every ``feedback_period_s``, the reported (motor-side) pose, stamped
      ``feedback_latency_s`` +- ``feedback_jitter_s`` (uniform) late.

    Reach and motion limits are :class:`RobotEnvelope`'s: in a cell configuration they are filled
    from ``[layout.robot]``.
    """

    repeatability_mm: Finite = Field(0.1, ge=0)
    repeatability_orientation_deg: Finite = Field(0.005, ge=0, le=1.0)
    absolute_accuracy_mm: Finite = Field(0.5, ge=0, le=50.0)
    absolute_accuracy_deg: Finite = Field(0.015, ge=0, le=1.0)
    accuracy_wavelength_mm: Finite = Field(2000.0, ge=100.0)
    call_latency_s: Finite = Field(0.004, ge=0, le=1.0)
    gripper_settle_s: Finite = Field(0.5, ge=0, le=10.0)  # the vacuum switching and settling before the gripper answers
    feedback_period_s: Finite = Field(0.004, gt=0, le=0.1)  # position feedback (EGM) sample period
    feedback_latency_s: Finite = Field(0.001, ge=0, le=0.1)  # a feedback sample's stamp is this late (mean)
    feedback_jitter_s: Finite = Field(0.0002, ge=0, le=0.01)  # plus uniform +-jitter per sample
    path_lag_s: Finite = Field(0.0003, ge=0, le=0.05)  # servo lag of the arm behind the reported path (v * lag mm)
    path_sideways_s: Finite = Field(0.0001, ge=0, le=0.01)  # sideways path deviation per TCP speed (mm per mm/s)
    home_position_mm: Vec3 = (1000.0, 0.0, 1600.0)
    home_xyz_fixed_deg: Vec3 = (180.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _reach(self) -> "RobotSimConfig":
        if 2.0 * self.feedback_jitter_s >= self.feedback_period_s:
            raise ValueError(
                f"feedback_jitter_s ({self.feedback_jitter_s:g}) must stay below half of feedback_period_s "
                f"({self.feedback_period_s:g}) so the feedback samples keep their order"
            )
        check_reach_order(self.min_reach_mm, self.reach_mm)
        dist = self.reach_distance(self.T_B_H_home())
        if not (self.min_reach_mm <= dist <= self.reach_mm):
            raise ValueError(
                f"home_position_mm puts the wrist centre {dist:.0f} mm from reach_centre_mm, outside the "
                f"robot's reach {self.min_reach_mm:g}..{self.reach_mm:g} mm; choose a home pose inside it"
            )
        return self

    def T_B_H_home(self) -> Pose:
        """The flange pose the robot starts at (XYZ fixed angles rx, ry, rz as in eq. 13)."""
        return pose_from_xyz_fixed_deg(self.home_position_mm, self.home_xyz_fixed_deg)


class LaserSimConfig(LaserMount):
    """LK-G500 on the fixture: mounting (eq. 19) and error sources.

    Error sources (each one off when 0): ``linearity_fraction_fs`` (paper: +-0.02 % of the full
    scale, a fixed smooth curve over the range, seeded) and ``noise_mm`` (repeatability, one sigma,
    drawn per reading). ``no_return_status`` is what a reading says when the beam finds no surface
    (through the window opening): the LK-G shows over range; which sign it takes for a missing
    return is not confirmed by the manual pages at hand, so it is a setting. Stored readings (the
    LK-G's data storage) measure where the flange was ``storage_latency_s`` before their instant, and
    reading them out takes ``readout_s_per_reading`` each (the serial line's time).
    """

    linearity_fraction_fs: Finite = Field(0.0002, ge=0, le=0.05)  # +-0.02 % of full scale (paper)
    noise_mm: Finite = Field(0.002, ge=0, le=10.0)  # repeatability of the LK-G500 head, one sigma
    no_return_status: Literal["over_range_far", "over_range_near", "no_value"] = "over_range_far"
    read_latency_s: Finite = Field(0.002, ge=0, le=1.0)  # one M1 round trip at 115200 Bd
    storage_latency_s: Finite = Field(0.008, ge=0, le=1.0)  # a stored reading's delay: head response plus averaging
    # Reading the storage out (AO) takes this per reading: 9 characters of 10 bits at 115200 Bd (RS-232C, 8N1).
    readout_s_per_reading: Finite = Field(9 * 10 / 115200, ge=0, le=0.1)


class CameraSimConfig(StrictModel):
    """The camera (eq. 17), its mounting (eq. 18), and the time a frame takes on the cell's clock."""

    intrinsics: CameraIntrinsics = CameraIntrinsics()
    hand_eye: HandEye = HandEye()
    render: RenderConfig = RenderConfig()
    # Trigger to frame in memory: a 5 ms exposure, then 2048 x 2048 x 8 bit (4.2 MB) over GigE Vision at about 110 MB/s.
    frame_time_s: Finite = Field(0.045, ge=0, le=10.0)


class GlassConfig(StrictModel):
    """The glass on the gripper: its upper-right corner frame G in the flange frame H, and how it looks.

    G is defined like T (x right, y down, z into the wall when installed); a correct install puts
    G onto T, G's x-y plane being the glass's outer surface. The default holds the glass with its
    plane parallel to the flange plane (paper 2.1: the fixture plane is parallel to the flange
    plane) and its centre on the flange axis; ``rotation_xyz_fixed_deg`` (rx, ry, rz, eq. 13
    order) tilts it, as a gripper that holds it slightly askew would.

    Outline: the opening's rounded rectangle (``width_mm`` x ``height_mm`` at G, as the opening's
    at T) inset by ``edge_gap_mm``, concentric, its corner radius the opening's minus the gap: the
    glass's right edge lies at x_G = -gap, its top edge at y_G = +gap. Along its edge runs the dark
    ceramic frit band, ``frit_width_mm`` wide; beyond it the clear glass shows the car interior.
    Greys (DN like ``wall_dn``) are drawn per car body within their ranges. ``gap_dn`` is the grey
    of what the camera sees between the glass's and the opening's edges; unset, the flange the
    glass is bonded to (the first band inside the opening's edge of the drawn surface) runs on
    under the glass. The laser reads the outer surface's front reflection: a weaker signal than the
    painted wall's, so ``laser_noise_mm`` (one sigma) replaces the wall's noise there, and a reading
    comes back without a value with ``laser_dropout_probability``. The simulated cell refuses a glass larger
    than the opening it goes into (:func:`glass_size_problem`): one made for another recipe's opening.
    """

    width_mm: Finite = Field(2000.0, gt=0)
    height_mm: Finite = Field(1500.0, gt=0)
    corner_in_flange_mm: Vec3 = (1000.0, -750.0, 120.0)
    rotation_xyz_fixed_deg: Vec3 = (0.0, 0.0, 0.0)
    edge_gap_mm: Finite = Field(5.0, gt=0, le=50)
    thickness_mm: Finite = Field(6.0, gt=0, le=40)
    frit_width_mm: Finite = Field(25.0, gt=0, le=300)
    frit_dn: Range = (9.0, 14.0)
    clear_dn: Range = (24.0, 32.0)
    gap_dn: Range | None = None
    laser_noise_mm: Finite = Field(0.004, ge=0, le=10.0)
    laser_dropout_probability: Finite = Field(0.02, ge=0, lt=1)

    @field_validator("frit_dn", "clear_dn", "gap_dn")
    @classmethod
    def _grey(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and v[1] > 255:
            raise ValueError(f"must lie in [0, 255] DN, got [{v[0]:g}, {v[1]:g}]")
        return v

    @field_validator("gap_dn", mode="before")
    @classmethod
    def _gap_off(cls, v: object) -> object:
        return None if v is False else v

    @model_validator(mode="after")
    def _outline(self) -> "GlassConfig":
        inner = min(self.width_mm, self.height_mm) / 2.0 - self.edge_gap_mm
        if inner <= 0:
            raise ValueError(
                f"edge_gap_mm ({self.edge_gap_mm:g}) leaves no glass in the {self.width_mm:g} x {self.height_mm:g} mm "
                "outline; it is the gap between the glass's and the opening's edges, a few mm"
            )
        if self.frit_width_mm >= inner:
            raise ValueError(
                f"frit_width_mm ({self.frit_width_mm:g}) must stay within the glass: the frit bands of opposite edges "
                f"would meet ({inner:g} mm from the edge to the centre); narrow it"
            )
        return self

    def T_H_G(self) -> Pose:
        """The glass corner frame in the flange frame."""
        return pose_from_xyz_fixed_deg(self.corner_in_flange_mm, self.rotation_xyz_fixed_deg)


class SimOperatorConfig(StrictModel):
    """The engineer of the simulated cell, who answers commissioning prompts by acting on the twin.

    ``answers``: "all" answers every prompt (the simulated cell commissions itself, and the CLI
    shows the answers); "actions" does what needs hands in the cell (places the car body, sticks
    the board on the wall, guides the glass) and leaves the confirmations that the first pose is
    clear to a person at the CLI or the dashboard; "none" answers nothing. Each hand-guided
    install is the exact install plus an error drawn per axis in the glass corner frame, one sigma
    ``hand_guiding_position_mm`` / ``hand_guiding_orientation_deg``.
    """

    answers: Literal["all", "actions", "none"] = "all"
    answer_delay_s: Finite = Field(0.0, ge=0, le=60)  # think time before each answer (dashboards see the prompt)
    hand_guiding_position_mm: Finite = Field(0.05, ge=0, le=5)
    hand_guiding_orientation_deg: Finite = Field(0.02, ge=0, le=2)


class SimConfig(StrictModel):
    """Everything the twin needs; deterministic for a seed.

    Each error source draws from its own random stream derived from ``seed`` and the source's
    name, so switching one source off leaves every other source's draws unchanged.
    ``time_scale`` is how long a simulated second lasts in real seconds: 1.0 runs moves and
    latencies in real time, the default 0.001 keeps tests and demos fast, 0 makes them instant.
    """

    seed: int = Field(1, ge=0)
    time_scale: Finite = Field(0.001, ge=0, le=10.0)
    world: WorldConfig = WorldConfig()
    robot: RobotSimConfig = RobotSimConfig()
    laser: LaserSimConfig = LaserSimConfig()
    camera: CameraSimConfig = CameraSimConfig()
    glass: GlassConfig = GlassConfig()
    operator: SimOperatorConfig = SimOperatorConfig()

    @model_validator(mode="after")
    def _glass_fits_the_opening(self) -> "SimConfig":
        radius = self.world.corner_radius_mm
        if self.glass.edge_gap_mm >= radius:
            raise ValueError(
                f"sim.glass.edge_gap_mm ({self.glass.edge_gap_mm:g}) must be smaller than the opening's corner radius "
                f"({radius:g} mm): the glass's corners are the opening's, inset by the gap (radius {radius:g} - gap)"
            )
        return self


# How much larger than its opening the twin's glass may be, in gaps (sim.glass.edge_gap_mm): its outline is drawn at
# the corner, so a glass larger by d leaves the far gaps gap - d. Half a gap (2.5 mm at 5 mm) takes a pane's size
# tolerance (about a millimetre) and refuses a glass made for another opening (hundreds of mm off).
GLASS_OVERSIZE_GAPS = 0.5


def glass_size_problem(glass: GlassConfig, opening: OpeningLayout) -> str | None:
    """Why the twin's glass cannot go into ``opening`` (``sim.world``: the layout's, a recipe's in its view), or None:
    its outline (width_mm x height_mm inset by edge_gap_mm) must fit the opening inset by the gap, within
    :data:`GLASS_OVERSIZE_GAPS`. The simulated cell asks (a real cell has no twin's glass); the message starts
    with the field."""
    gap = glass.edge_gap_mm
    for field, size, room in (("width_mm", glass.width_mm, opening.width_mm), ("height_mm", glass.height_mm, opening.height_mm)):
        if size - room > GLASS_OVERSIZE_GAPS * gap:
            far = room - size + gap  # the far gap: the glass's far edge inside the opening's
            where = f"{-far:g} mm over the opening's, on the wall" if far <= 0 else f"only {far:g} mm inside the opening's"
            return (f"sim.glass.{field} = {size:g} is larger than the opening's {field} = {room:g} ([layout.opening], or a "
                    f"recipe's own): inset by edge_gap_mm = {gap:g}, the glass's far edge lies {where} (at least "
                    f"{(1 - GLASS_OVERSIZE_GAPS) * gap:g} mm inside it): give the twin the glass made for this opening, its "
                    "width_mm, height_mm and corner_in_flange_mm (a recipe's in [process.recipes.sim_glass])")  # fmt: skip
    return None
