"""What every route shares: the id parameters and the one error body.

The bodies of each area are next to this module: ``schemas_cell`` (status, commands, alarms,
calibration, health), ``schemas_cycles``, ``schemas_jobs`` and ``schemas_dashboard``. The OpenAPI
document is generated from them; a route that answers JSON names its model, so the document says
what it returns.
"""

from __future__ import annotations

from typing import Annotated

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
