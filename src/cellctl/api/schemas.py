"""Request and response bodies of the REST API (the OpenAPI schema is generated from these)."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field


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


class ErrorBody(BaseModel):
    detail: str
    errors: list[dict[str, Any]] = []
