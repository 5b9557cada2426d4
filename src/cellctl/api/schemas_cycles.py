"""Bodies of the cycle routes: ``POST /cycle`` and the cycle records (``/cycles``, ``/cycles/{id}``).

Times are ISO 8601 text (UTC); steps and images are named in lower case (``align``, ``shoot``).
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator
from pydantic_core import PydanticCustomError

from cellctl.domain import InstallDeviation
from cellctl.store.records import NAME_ALLOWED, NAME_PATTERN, TEXT_ALLOWED, TEXT_PATTERN, text_problem


class CycleRequestBody(BaseModel):
    """Start one installation cycle."""

    model_config = ConfigDict(extra="forbid")

    recipe: str = Field(min_length=1, max_length=64, description="recipe name, e.g. 'side-window'")
    part_id: str = Field(min_length=1, max_length=64, pattern=NAME_PATTERN,
                         description=f"the glass part's id; {NAME_ALLOWED}")  # fmt: skip
    car_id: str | None = Field(None, max_length=64, pattern=TEXT_PATTERN,
                               description=f"the car body's id, if known; {TEXT_ALLOWED}. Omitted, null, empty or only "
                               "white space: not known (recorded as null)")  # fmt: skip

    @field_validator("part_id", "car_id", mode="before")
    @classmethod
    def _printable(cls, value: object, info: ValidationInfo) -> object:
        """The store's rule (cellctl.store.records) said in words; a blank car_id is no car_id (as over OPC UA)."""
        if not isinstance(value, str):
            return value  # the field's type says what is wrong
        problem = text_problem(value, required=info.field_name == "part_id")
        if problem is not None:
            raise PydanticCustomError("text_not_allowed", "{problem}", {"problem": problem})
        return None if info.field_name == "car_id" and not value.strip() else value


class CycleAccepted(BaseModel):
    """A cycle queued (or found again under its Idempotency-Key)."""

    cycle_id: int
    state: str
    created: bool = Field(description="false: this Idempotency-Key was seen before; this is that cycle")
    links: dict[str, str]


class StepView(BaseModel):
    """One run of one cycle step (compensate's verification shots make several shoot attempts)."""

    step: str
    attempt: int
    started_at: str
    duration_s: float | None
    ok: bool | None = Field(description="None while the step runs")
    figures: dict[str, Any] = Field(description="the step's figures (e.g. align's plane fit, compensate's offset)")
    error: str | None


class ImageView(BaseModel):
    """An image of a cycle; once retention deleted its file, when and why."""

    name: str
    step: str
    url: str = Field(description="GET it for the PNG (410 once pruned)")
    pruned_at: str | None
    pruned_reason: str | None


class CycleBrief(BaseModel):
    """A cycle record without its steps and images (``GET /cycles``)."""

    id: int
    state: str = Field(description="queued, running, done, failed or interrupted")
    recipe: str
    part_id: str
    car_id: str | None
    source: str = Field(description="who asked for it, e.g. rest:127.0.0.1 or plc")
    actor: str
    idempotency_key: str
    current_step: str
    result: dict[str, Any] | None = Field(description="ok, error_code, correction_mm, correction_deg, shots, cycle_time_s")
    error: str | None = Field(description="why it failed")
    true_error: dict[str, Any] | None = Field(
        description="the simulated cell's known install error (None on hardware, and for a cycle whose install never began)"
    )
    measured_deviation: InstallDeviation | None = Field(
        description="the install deviation the cell measured after the install: gaps in the image (dx, dy, drz) and "
        "the laser's flush (dz, drx, dry), against the opening; None when not measured"
    )
    part_ok: bool | None = Field(description="the measured deviation within the tolerance; None when not measured")
    created_at: str
    started_at: str | None
    finished_at: str | None
    install_started_at: str | None = Field(description="set before the robot was commanded to install")
    interrupted_step: str | None = Field(description="the step the service was in when it died")


class CycleView(CycleBrief):
    """A cycle record with its steps and images (``GET /cycles/{id}``)."""

    steps: list[StepView]
    images: list[ImageView]
