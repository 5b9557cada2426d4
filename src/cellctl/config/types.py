"""Shared building blocks of the configuration schema."""

from __future__ import annotations

import math
from typing import Annotated

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict


class StrictModel(BaseModel):
    """Unknown fields are refused (a typo must not silently fall back to a default)."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


def _finite(v: float) -> float:
    if not math.isfinite(v):
        raise ValueError("must be a finite number")
    return v


def _finite_vec(v: tuple[float, ...]) -> tuple[float, ...]:
    if not all(math.isfinite(x) for x in v):
        raise ValueError("all components must be finite numbers")
    return v


def _unit_direction(v: tuple[float, float, float]) -> tuple[float, float, float]:
    n = math.sqrt(sum(x * x for x in v))
    if not math.isfinite(n) or n < 1e-9:
        raise ValueError("must be a non-zero direction")
    if abs(n - 1.0) > 1e-3:
        raise ValueError(f"must be a unit vector (its length is {n:.6f}); divide it by its length")
    return (v[0] / n, v[1] / n, v[2] / n)


Finite = Annotated[float, AfterValidator(_finite)]
Vec2 = Annotated[tuple[float, float], AfterValidator(_finite_vec)]
Vec3 = Annotated[tuple[float, float, float], AfterValidator(_finite_vec)]
UnitVec3 = Annotated[tuple[float, float, float], AfterValidator(_unit_direction)]
Matrix3Rows = tuple[Vec3, Vec3, Vec3]


def as_array(v: tuple[float, ...] | tuple[tuple[float, ...], ...]) -> np.ndarray:
    """A config tuple as a float numpy array."""
    return np.asarray(v, dtype=float)


def check_unique(section: str, what: str, values: list[object]) -> None:
    """Raise ValueError naming the section unless every entry's ``what`` differs."""
    if len(set(values)) != len(values):
        raise ValueError(f"{section}: each entry needs its own {what}, got {values}")
