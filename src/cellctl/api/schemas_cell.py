"""Bodies of the cell routes: ``/status``, PackML commands and modes, ``/alarms``, ``/calibration``, ``/health``.

Times are ISO 8601 text (UTC) as the cell wrote them. Some objects carry keys only when they
apply (an oracle calibration has no versions, a status part only exists in a service that has it);
their routes answer with the keys that were set (``response_model_exclude_unset``), so a field
here that is left out stays out of the answer rather than appearing as null.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from cellctl.api.schemas_jobs import RunningJob
from cellctl.api.schemas_quality import SpcStatus


class CommandResult(BaseModel):
    """A PackML command or unit mode change the state table took."""

    command: str = Field(description="the command's name, or mode:<name> for a unit mode change")
    state: str = Field(description="the PackML state after it (e.g. RESETTING)")
    mode: str = Field(description="the unit mode after it (e.g. PRODUCTION)")


# -- /status ------------------------------------------------------------------------------------


class StopBrief(BaseModel):
    """The alarm that stopped the cell, in brief (``GET /alarms`` has it in full)."""

    code: int
    message: str


class DeviceHealth(BaseModel):
    """One device as the watchdog sees it."""

    link: str = Field(description="up, degraded or lost")
    heartbeat_age_s: float | None = Field(description="time since its last answer (None: it never answered)")
    round_trip_s: float | None = Field(description="its last answer's round trip")


class LinkReport(BaseModel):
    """A link outside the devices (the PLC): its state since when, and any figures it reported."""

    model_config = ConfigDict(extra="allow")

    link: str = Field(description="waiting, up or lost")
    since_utc: str
    silent_for_s: float | None = Field(None, description="with lost: how long the PLC's heartbeat has been silent")


class RecipeProblems(BaseModel):
    """Whether one recipe's cycles would find the calibration ready, and if not why."""

    ready: bool = Field(description="no problems: its cycles would find the calibration ready")
    problems: list[str] = Field(description="what keeps it from production, the cell's parts included, one line each "
                                            "naming the command that mends it (empty: ready)")


class CalibrationProblems(BaseModel):
    """Why production may not start now (empty: it may), for the cell's first recipe and for each recipe."""

    problems: list[str] = Field(description="what keeps the cell's first recipe from production (the cell's parts "
                                            "included); empty: it may start")
    recipes: dict[str, RecipeProblems] = Field(description="each recipe of [[process.recipes]], by name: a cycle of a "
                                                           "recipe whose own parts are not ready is refused (409)")


class PrunedCounts(BaseModel):
    """What retention deleted since the service started."""

    images: int
    orphan_files: int
    cycles: int
    alarms: int


class RetentionSettings(BaseModel):
    """The ``[store.retention]`` settings in force."""

    enabled: bool
    images_days: float
    images_max_gb: float
    cycles_days: float | str = Field(description='days, or "forever"')
    alarms_days: float | str = Field(description='days, or "forever"')
    audit_log: str
    disk_warn_free_gb: float
    disk_stop_free_gb: float


class StorageStatus(BaseModel):
    """Disk and retention figures as of the last retention pass or disk check (None: not measured yet)."""

    images_mb: float | None
    images_count: int | None
    oldest_image_utc: str | None
    database_mb: float | None
    free_disk_gb: float | None
    disk: str = Field(description="ok, low, critical or unknown (a file system not measured: last_error names it)")
    checked_utc: str | None
    last_pass_utc: str | None
    last_error: str | None
    pruned_since_start: PrunedCounts
    retention: RetentionSettings


class StatusView(BaseModel):
    """A snapshot of the cell: PackML state and mode, the cycle, devices, links and what blocks production.

    ``job`` and ``storage`` are there in a service that runs commissioning jobs and retention
    (``cellctl serve`` does); a service may add further parts (extra keys are passed on).
    """

    model_config = ConfigDict(extra="allow")

    cell_id: str
    service_mode: str = Field(description="sim or hardware")
    state: str = Field(description="PackML StateCurrent by name, e.g. EXECUTE")
    state_id: int = Field(description="PackML StateCurrent (PackTags integer)")
    mode: str = Field(description="PackML UnitModeCurrent by name, e.g. PRODUCTION")
    mode_id: int = Field(description="PackML UnitModeCurrent (PackTags integer)")
    cycle_step: str = Field(description="the sub-step of Execute (none outside a cycle)")
    current_cycle: int | None = Field(description="the running cycle's id")
    queued_cycles: int
    allowed_commands: list[str] = Field(description="the commands the state table takes now")
    blocked_commands: dict[str, str] = Field(description="commands held back now, with the reason (e.g. an alarm)")
    stop_reason: StopBrief | None
    devices: dict[str, DeviceHealth]
    links: dict[str, LinkReport]
    calibration: CalibrationProblems
    job: RunningJob | None = Field(None, description="the running commissioning job (None: none runs)")
    storage: StorageStatus | None = Field(None, description="disk and retention")
    spc: SpcStatus | None = Field(None, description="the closed loops over measured install results (one per recipe)")


# -- /alarms ------------------------------------------------------------------------------------


class AlarmView(BaseModel):
    """One alarm occurrence (PackML ``PackMLAlarmDataType`` plus what the cell needs)."""

    uid: str = Field(description="this occurrence's id (POST /alarms/{uid}/acknowledge)")
    code: int = Field(description="PackML ID, e.g. 1302 corner not found")
    value: int = Field(description="PackML Value: a sub-code, 0 if none")
    message: str
    category: str = Field(description="the fault class")
    severity: str
    source: str = Field(description="what raised it: laser, plc, cycle, ...")
    raised_at: str
    active: bool
    acknowledged: bool
    ack_by: str | None
    ack_at: str | None
    cleared_at: str | None
    reaction: str | None = Field(description="the command the cell issued for it, if any")
    cycle_id: int | None


class AlarmsView(BaseModel):
    """The current alarms and the one that stopped the cell; ``history`` with ``?history=true`` only."""

    current: list[AlarmView]
    stop_reason: AlarmView | None
    history: list[AlarmView] | None = Field(None, description="the last 200 alarms, newest first (with ?history=true)")


# -- /calibration -------------------------------------------------------------------------------


class CalibrationPartSummary(BaseModel):
    """One part of the calibration set in use."""

    status: str = Field(description="ok or failed")
    calibrated_utc: str
    expires_utc: str | None = Field(
        description="when it stops counting for production (ISO 8601, UTC): calibrated_utc plus the shorter of the "
        "validity recorded with it and calibration.max_age_days; null for a failed part"
    )
    method: str
    quality: dict[str, Any]
    failure: str | None


class RecipeReadiness(BaseModel):
    """Whether a recipe may run: its own teaching done, and everything its cycles need ready."""

    taught: bool = Field(description="its teaching is in the set (the oracle teaches every recipe from the truth)")
    ready: bool = Field(description="its cycles would find the calibration ready")
    problems: list[str] = Field(description="what keeps it from production, the cell's parts included, one line each "
                                            "naming the command that mends it (empty: ready)")


class CalibrationSummary(BaseModel):
    """The calibration in use. A set names its version and parts; the simulated cell's oracle its template."""

    model_config = ConfigDict(extra="allow")

    source: str = Field(description="the calibration set's folder, or 'twin truth (oracle)'")
    version: int | None = Field(None, description="the set's version in use (None: there is no set)")
    parts: dict[str, CalibrationPartSummary | None] | None = Field(None, description="each part of the set (None: not calibrated)")
    damaged: str | None = Field(None, description="why the set's file cannot be used, and what to do")
    template_px: list[float] | None = Field(None, description="oracle: the template corner (u, v) once computed")
    recipes: dict[str, RecipeReadiness] = Field({}, description="each recipe of [[process.recipes]], by name")
    warnings: list[str] = Field([], description="parts used although dated ahead of the cell's clock (check its NTP)")


class CalibrationVersion(BaseModel):
    """One stored version of the calibration set."""

    version: int
    created_utc: str | None
    note: str
    parts: dict[str, str | None] = Field(description="each part's status in this version (None: not in it)")
    recipes: dict[str, dict[str, str | None]] = Field({}, description="each recipe's own parts (but the first's) and their status")
    damaged: str | None = Field(None, description="why this version's file cannot be read")


class CalibrationView(BaseModel):
    """The calibration in use, why production may not start, and every stored version (oldest first)."""

    current: CalibrationSummary
    problems: list[str]
    versions: list[CalibrationVersion]
    now_utc: str = Field(
        description="the service's clock as it answered (ISO 8601, UTC): the parts' status is reckoned on it, and a "
        "client shows how far off expires_utc is against it, not against its own clock (a workstation's may be days off)"
    )


# -- /health ------------------------------------------------------------------------------------


class StoreHealth(BaseModel):
    """The database, without its path."""

    journal_mode: str = Field(description="SQLite journal mode (wal)")


class HealthView(BaseModel):
    """``ok``: the cell is ready (HTTP 200), else HTTP 503. Anonymous callers of a cell with closed reads get ``ok`` alone."""

    ok: bool
    devices_lost: list[str] | None = Field(None, description="devices the watchdog no longer hears (with the details)")
    plc: str | None = Field(
        None, description="the PLC link (with the details): up, waiting (no heartbeat yet), lost; absent with [plc] enabled = false"
    )
    problems: list[str] | None = Field(None, description="why the cell is not healthy, one line each (with the details); empty when ok")
    store: StoreHealth | None = Field(None, description="the database (with the details); never its path")


class LiveView(BaseModel):
    """``/health/live``: the process serves HTTP (liveness, not readiness)."""

    ok: bool = True
