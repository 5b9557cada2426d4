"""Bodies of the part traceability routes (``GET /parts``, ``GET /parts/{part_id}``, ``GET /part-history``).

One :class:`PartInstall` is the whole record of one install: what was asked, with which
calibration set, every step's figures, the images with their SHA-256 and the state of their
files now, the outcome and measured deviation, and what people (and the cell) did during it.
``cellctl parts export`` writes the same documents, one JSON object per line. Times are ISO 8601
with their offset (UTC); units are in the field names.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

from cellctl.api.schemas_cell import AlarmView
from cellctl.api.schemas_cycles import StepView
from cellctl.domain import InstallDeviation

ImageStatus = Literal["ok", "altered", "pruned", "missing", "unrecorded"]


class PartImage(BaseModel):
    """An image of the install, its digest as recorded, and what its file is now."""

    name: str
    step: str = Field(description="the cycle step that took it, e.g. shoot, inspect")
    uri: str = Field(description="the file, relative to the cell's image folder")
    url: str = Field(description="GET it for the PNG (410 once pruned or gone)")
    created_at: str
    sha256: str | None = Field(description="SHA-256 (hex) of the PNG as written; null for images recorded before digests were kept")
    size_bytes: int | None = Field(description="the PNG's size as written")
    status: ImageStatus = Field(
        description="the file now: ok (present, SHA-256 matches), altered (present, SHA-256 differs), pruned (retention "
        "deleted it: see pruned_at, pruned_reason), missing (no readable file, not pruned), unrecorded (present, "
        "but no digest was recorded to check it against)"
    )
    pruned_at: str | None
    pruned_reason: str | None


class PartAction(BaseModel):
    """An audit-log entry filed under the install's cycle: a command and who gave it, a state change, the loop's update."""

    seq: int = Field(description="the entry's number in the hash-chained audit log")
    at: str
    actor: str = Field(description="the token's name for a person or system, or the cell itself")
    source: str = Field(description="where it came from, e.g. rest:10.0.0.5, plc, cell")
    action: str = Field(description="e.g. command:hold, sc, spc.update")
    params: dict[str, Any]
    state_before: str | None
    state_after: str | None
    result: str
    hash: str = Field(description="the entry's SHA-256 in the audit log's hash chain (each entry links to the one before)")


class PartInstall(BaseModel):
    """Everything recorded about one install of one glass (one cycle)."""

    cycle_id: int
    recipe: str
    part_id: str = Field(description="the glass")
    car_id: str | None = Field(description="the car body, if the request named it")
    source: str = Field(description="who asked for the cycle, e.g. rest:127.0.0.1 or plc")
    actor: str
    state: str = Field(description="queued, running, done, failed or interrupted")
    created_at: str
    started_at: str | None
    finished_at: str | None
    install_started_at: str | None = Field(description="when the robot was first commanded to install (null: never)")
    interrupted_at: str | None = Field(description=(
        "when the service's stop cut the cycle off, as far as its record shows: its last step start or end or image "
        "(else its start); its record was closed, and a since/until window lists it, when the service next started"))
    ended_at: str | None = Field(None, description=(
        "when the cell closed the record (done, failed, or interrupted when the service next started), the time a "
        "since/until window is on: the cell's clock, but never before an earlier record's, so a clock stepped back "
        "puts no install into a window already exported (null while the cycle runs)"))
    interrupted_step: str | None
    calibration_version: str | None = Field(description="the calibration set version the cycle ran with")
    recipe_settings: str | None = Field(None, description=(
        "the id of the recipe's settings the cycle ran with (`settings-` and 12 hex digits of their SHA-256: the tables "
        "a recipe may set and the tolerance, as that recipe's view holds them); another id under the same recipe name "
        "is an edited definition (null: recorded before the cell kept it)"))
    ok: bool | None = Field(description="installed and measured inside the tolerance; null while the cycle runs")
    error_code: int | None = Field(description="0 when ok, else the alarm code that says why (null while it runs)")
    reason: str | None = Field(description="why it is not ok (empty when ok)")
    measured_deviation: InstallDeviation | None = Field(
        description="the deviation the cell measured after the install (gaps in the image, the laser's flush); null when not measured"
    )
    correction_mm: list[float] | None = Field(description="the workpiece correction applied (x, y, z); null when none was computed")
    correction_deg: list[float] | None = Field(description="the correction's rotation (rx, ry, rz; XYZ fixed angles)")
    cycle_time_s: float | None
    steps: list[StepView] = Field(description="every step attempt with its figures, duration, ok and error")
    images: list[PartImage]
    actions: list[PartAction] = Field(description="the audit-log entries filed under this cycle, oldest first")
    alarms: list[AlarmView] = Field(description="the alarms of this cycle: raised, acknowledged (by whom), cleared")


class PartsPage(BaseModel):
    """``GET /parts``: installs by ascending cycle id."""

    installs: list[PartInstall]
    next: int | None = Field(description="pass as ?after= (same filters) for the next page; null on the last page")
    until: str | None = Field(None, description="the window's end as applied (ISO 8601, UTC): `until`, but no later "
                              "than the latest install's `ended_at` + 1 us (every later install ends at or after it) and "
                              "never before `since` (an empty window); pass it as `until` for the next pages and as the "
                              "next window's `since`")


class PartHistory(BaseModel):
    """``GET /parts/{part_id}`` and ``GET /part-history?part_id=``: every install of one glass, oldest first."""

    part_id: str
    installs: list[PartInstall]
