"""Request and response bodies of the REST API (the OpenAPI schema is generated from these)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Path, Query
from pydantic import BaseModel, ConfigDict, Field

SQLITE_INT_MAX = 2**63 - 1
"""The largest id a record can have (SQLite INTEGER is 64-bit signed); a larger one is refused with 422."""

CycleId = Annotated[int, Path(ge=1, le=SQLITE_INT_MAX, description="a cycle's id (GET /cycles)")]
JobId = Annotated[int, Path(ge=1, le=SQLITE_INT_MAX, description="a commissioning job's id (GET /jobs)")]
PromptId = Annotated[int, Path(ge=1, le=SQLITE_INT_MAX, description="the id of the job's open prompt")]
BeforeId = Annotated[
    int | None, Query(ge=1, le=SQLITE_INT_MAX, description="only cycles with a smaller id (the next page)")
]


class CycleRequestBody(BaseModel):
    """Start one installation cycle."""

    model_config = ConfigDict(extra="forbid")

    recipe: str = Field(min_length=1, max_length=64, description="recipe name, e.g. 'side-window'")
    part_id: str = Field(min_length=1, max_length=64, description="the glass part's id")
    car_id: str | None = Field(None, max_length=64, description="the car body's id, if known")


class CycleAccepted(BaseModel):
    cycle_id: int
    state: str
    created: bool = Field(description="false: this Idempotency-Key was seen before; this is that cycle")
    links: dict[str, str]


class CommandResult(BaseModel):
    command: str
    state: str
    mode: str


class FieldError(BaseModel):
    """One bad field of a request."""

    model_config = ConfigDict(populate_by_name=True)

    where: str = Field(alias="in", description="path, query, header or body")
    field: str = Field(description="the field's name (dotted for nested body fields)")
    message: str
    type: str | None = Field(None, description="pydantic's error type, e.g. missing, int_parsing, less_than_equal")


class ErrorBody(BaseModel):
    """Every error answer (4xx): ``detail`` says what is wrong in a sentence; a refused request lists its bad fields."""

    detail: str = Field(description="what is wrong and, where it can, what to do")
    errors: list[FieldError] = Field([], description="with 422 for a bad request: each bad field")


class StoreHealth(BaseModel):
    journal_mode: str = Field(description="SQLite journal mode (wal)")


class HealthView(BaseModel):
    """``ok``: every device answers. Anonymous callers of a cell with closed reads get ``ok`` alone."""

    ok: bool
    devices_lost: list[str] | None = Field(None, description="devices the watchdog no longer hears (with the details)")
    store: StoreHealth | None = Field(None, description="the database (with the details); never its path")


# -- commissioning jobs -------------------------------------------------------------------------


class JobOptions(BaseModel):
    """Options of a commissioning job; each procedure takes some of them (others are refused)."""

    model_config = ConfigDict(extra="forbid")

    views: int | None = Field(None, description="camera, hand_eye: board views to plan (default calibration.procedure.camera.n_views)")
    poses: int | None = Field(None, description="laser: poses to plan (default calibration.procedure.laser.n_poses)")
    method: str | None = Field(None, description="hand_eye: the method whose result is stored (default tsai)")
    store: bool | None = Field(None, description="false: compute and report only; the calibration set is not changed")


class JobRequestBody(BaseModel):
    """Start (or plan) one commissioning job."""

    model_config = ConfigDict(extra="forbid")

    procedure: str = Field(description="camera, hand_eye, laser, teaching, pixel_map or verify")
    options: JobOptions = JobOptions()


class PromptAnswerBody(BaseModel):
    """The engineer's answer to a job's open prompt."""

    model_config = ConfigDict(extra="forbid")

    action: str = Field(description="confirm, cancel, or value (a confirmation with a number)")
    value: float | None = Field(None, description="the value, for action 'value' (e.g. the measured square size in mm)")


class PromptView(BaseModel):
    id: int
    job_id: int
    kind: str = Field(description="car_body_in_place, place_board, remove_board, confirm_start, guide_install or retreat")
    text: str
    details: dict[str, Any]
    value_label: str | None
    default: float | None
    created_utc: str


class JobView(BaseModel):
    """A commissioning job: what it does, where it stands, what it found."""

    id: int
    procedure: str
    state: str = Field(description="running, computing, done, refused, failed, cancelled or interrupted")
    actor: str
    source: str
    options: dict[str, Any]
    created_utc: str
    finished_utc: str | None
    plan: dict[str, Any] | None = Field(description="the plan shown before the first move (poses, robot time, rotation spread)")
    progress: dict[str, Any] | None = Field(description="done, total, message, elapsed_s, time_left_s")
    dataset: str | None = Field(description="the dataset folder (a partial one if the job ended early)")
    result: dict[str, Any] | None = Field(description="summary lines, quality figures, warnings, the stored version")
    error: str | None = Field(description="why the job was refused, failed or cancelled")
    version_before: int | None
    version_after: int | None = Field(description="the calibration-set version the job stored, if any")
    prompt: PromptView | None = Field(description="the open prompt, while the job waits for the engineer")
    frames: int = Field(description="frames grabbed so far; after the job, 1 while its last frame is kept (GET /jobs/{id}/image)")
    running: bool


class PlanView(BaseModel):
    """A job's plan without running it (``--dry-run``)."""

    procedure: str
    poses: int
    dropped: list[str]
    speed_mm_s: float
    speed_deg_s: float
    estimated_robot_time_s: float
    rotation: dict[str, float]
    details: dict[str, Any]
    first_pose: dict[str, Any] | None = None
    pose_list: list[dict[str, Any]] = []


class ProcedureView(BaseModel):
    name: str
    part: str
    dataset_kind: str
    needs: list[str]
    options: list[str]
    command: str
    defaults: dict[str, Any] = Field(description="what an option left out means (e.g. views 12, poses 480)")
    limits: dict[str, list[float]] = Field(description="the range each number option takes")
    choices: dict[str, list[str]] = Field(description="the values a choice option takes (hand_eye's method)")
