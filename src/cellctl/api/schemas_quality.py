"""Response models of the closed loop over measured install results (``/spc``)."""

from __future__ import annotations

from pydantic import BaseModel, Field


class SpcDrift(BaseModel):
    axis: str
    kind: str = Field(description="trend (the estimate passed the limit) or step (results jumped past the gate)")
    value: float = Field(description="the estimate (trend) or the last deviation without the loop (step)")
    limit: float
    gate: float | None = Field(None, description="a step: the gate its results failed (about the estimate, or the install tolerance)")
    tested: float | None = Field(None, description="a step: what that gate refused in its last result (axis unit)")


class SpcView(BaseModel):
    """A recipe's loop now: whether it applies its offset, the estimate per axis, the offset the next install takes out."""

    recipe: str = Field(description="the recipe whose installs this loop follows (each recipe has its own)")
    enabled: bool = Field(description="false: the loop estimates and watches for drift but applies no offset")
    calibration_version: str | None
    samples: int = Field(description="results counted since the last reset")
    min_samples: int = Field(description="results before the EWMA and its outlier gate start (until then the estimate is their running mean)")
    estimate: dict[str, float | None] = Field(description="per axis (dx_mm ... drz_deg): the deviation without the loop (None before a result)")
    offset: dict[str, float] | None = Field(description="what the next install takes out (None when disabled)")
    excluded: dict[str, int] = Field(description="results not counted, by reason")
    drifting: list[SpcDrift]
    limits: dict[str, float]
    updated_at: str | None


class SpcStatus(SpcView):
    """``/status``'s ``spc``: the cell's first recipe's loop, and every recipe's in the configuration's order."""

    recipes: list[SpcView]


class SpcHistoryEntry(BaseModel):
    id: int
    recorded_at: str
    recipe: str = Field(description="the recipe whose loop this row updated")
    cycle_id: int | None
    calibration_version: str | None
    events: list[str]
    excluded: str | None
    u: dict[str, float] | None = Field(description="the cycle's deviation without the loop (measured + applied offset)")
    estimate: dict[str, float | None]
    offset: dict[str, float]
    drifting: list[str]


class SpcPage(BaseModel):
    """``GET /spc``: a recipe's loop (the first recipe's unless asked for another), and the latest updates
    of that loop (of every loop when no recipe is asked for), oldest first."""

    now: SpcView
    recipes: list[SpcView] = Field(description="every recipe's loop, in the configuration's order")
    history: list[SpcHistoryEntry]
