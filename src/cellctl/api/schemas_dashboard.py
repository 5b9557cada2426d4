"""Bodies of the dashboard's own feeds: ``/dashboard/config``, ``/dashboard/shifts`` and ``/dashboard/cycles``."""

from __future__ import annotations

from pydantic import BaseModel, Field

from cellctl.domain import InstallDeviation


class Tolerance(BaseModel):
    """The recipe tolerance the trend charts draw as bands."""

    position_mm: float
    orientation_deg: float


class DashboardConfig(BaseModel):
    """What the page needs besides the API: tolerance bands, the mode-change states and the live-feed timing."""

    tolerance: Tolerance
    simulation: bool = Field(description="the simulated cell (the page then shows the true install error)")
    plc_enabled: bool
    plc_heartbeat_alarm: bool
    mode_change_states: list[str] = Field(description="PackML states in which the unit mode may change")
    status_period_s: float = Field(description="/events sends a status event at least this often")
    stale_after_s: float = Field(description="the page marks its data stale after this long without an event")
    calibration_max_age_days: float = Field(description="a calibration part older than this keeps the cell from production")
    shift_starts: list[str] = Field(description="local times (HH:MM) at which a shift begins, earliest first")


class ShiftCount(BaseModel):
    """One shift's cycles: good parts, not OK ones (failed, interrupted or measured out of tolerance)."""

    start_utc: str
    end_utc: str
    start_local: str = Field(description="the shift's start in the asked time zone, YYYY-MM-DD HH:MM")
    current: bool
    good: int
    not_ok: int
    median_cycle_time_s: float | None = Field(description="the takt: median cycle time of the shift's good cycles")


class ShiftCounts(BaseModel):
    """The current shift and the ones before it, newest first."""

    shift_starts: list[str]
    tz: str | None = Field(description="the time zone asked (IANA name): each shift's bounds in its offset then; null: tz_offset_min")
    tz_offset_min: int = Field(description="minutes east of UTC: the asked zone's offset now, or the one offset asked")
    shifts: list[ShiftCount]


Deviation = InstallDeviation
"""Six figures of an install: offsets in mm, rotations in degrees (one definition, cellctl.domain)."""


class Residual(BaseModel):
    """The last verification shot's in-plane offset; the laser-aligned figures are not measured by it (None)."""

    dx_mm: float
    dy_mm: float
    dz_mm: None
    drx_deg: None
    dry_deg: None
    drz_deg: float


class DigestImage(BaseModel):
    """A cycle's last annotated image, full size and as a filmstrip thumbnail."""

    name: str
    step: str
    url: str
    thumb: str


class CycleDigest(BaseModel):
    """One cycle as the trend charts and the filmstrip need it (None: the cycle did not measure it)."""

    id: int
    state: str
    part_id: str
    car_id: str | None
    recipe: str
    created_at: str
    finished_at: str | None
    current_step: str
    error: str | None
    cycle_time_s: float | None
    measured: Deviation | None = Field(description="the install deviation the cell measured (gaps and flush)")
    part_ok: bool | None = Field(None, description="the measured deviation within the tolerance")
    true_error: Deviation | None = Field(description="the twin's six install errors (simulation only)")
    correction: Deviation | None = Field(description="the workpiece correction the cycle applied")
    residual: Residual | None = Field(description="the last verification shot's offset from the template")
    image: DigestImage | None
