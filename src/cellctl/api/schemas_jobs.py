"""Bodies of the commissioning routes (``/procedures``, ``/jobs``): calibration, teaching and verification jobs."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field


class JobOptions(BaseModel):
    """Options of a commissioning job; each procedure takes some of them (others are refused)."""

    model_config = ConfigDict(extra="forbid")

    views: int | None = Field(None, description="camera, hand_eye: board views to plan (default calibration.procedure.camera.n_views)")
    poses: int | None = Field(None, description="laser: poses to plan (default calibration.procedure.laser.n_poses)")
    method: str | None = Field(None, description="hand_eye: the method whose result is stored (default tsai)")
    store: bool | None = Field(None, description="false: compute and report only; the calibration set is not changed")
    recipe: str | None = Field(None, description="teaching, pixel_map: the recipe taught (a [[process.recipes]] name; default the first)")


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
    """A question a job asks the engineer (what to do by hand, or the confirmation before a move)."""

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
    """A commissioning procedure: the part it calibrates, what it needs first, its options."""

    name: str
    part: str
    dataset_kind: str
    needs: list[str]
    options: list[str]
    command: str
    defaults: dict[str, Any] = Field(description="what an option left out means (e.g. views 12, poses 480)")
    limits: dict[str, list[float]] = Field(description="the range each number option takes")
    choices: dict[str, list[str]] = Field(description="the values a choice option takes (hand_eye's method)")


class RunningJob(BaseModel):
    """The running job in ``GET /status`` (its full view is ``GET /jobs/{id}``)."""

    id: int
    procedure: str
    state: str = Field(description="running or computing")
    progress: dict[str, Any] = Field(description="done, total, message, elapsed_s, time_left_s (as far as known)")
    prompt: str | None = Field(description="the kind of the open prompt, while the job waits for the engineer")
