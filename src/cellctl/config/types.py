"""Shared building blocks of the configuration schema."""

from __future__ import annotations

import math
from collections.abc import Sequence
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, ValidationError, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError


class StrictModel(BaseModel):
    """Unknown fields are refused (a typo must not silently fall back to a default).

    A TOML true/false is refused where a field (or an item of a list field) is a number: pydantic
    would take it as 1 or 0 (``plc.port = true`` would listen on port 1).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)

    @model_validator(mode="before")
    @classmethod
    def _no_bool_for_a_number(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        problems = []
        for name, field in cls.model_fields.items():
            key = field.alias or name
            if key in data and (where := bool_for_a_number(field.annotation, data[key])) is not None:
                problems.append(InitErrorDetails(type=_NOT_A_NUMBER, loc=(key, *where), input=data[key]))
        if problems:  # pydantic places these errors at the fields (pydantic-core merges a ValidationError's locations)
            raise ValidationError.from_exception_data(cls.__name__, problems)
        return data


_NOT_A_NUMBER = PydanticCustomError(
    "bool_for_a_number", "must be a number, not true/false: write the number itself (e.g. 1 or 0.5)"
)


def _members(tp: Any) -> list[Any]:
    """The types a field's annotation admits: its union's members, each without its Annotated metadata."""
    while get_origin(tp) is Annotated:
        tp = get_args(tp)[0]
    if get_origin(tp) in (Union, UnionType):
        return [m for arg in get_args(tp) for m in _members(arg)]
    return [tp]


def _number_not_bool(tp: Any) -> bool:
    """Whether ``tp`` takes a number but not true/false (a bool is an int to Python and to pydantic's lax mode)."""
    members = _members(tp)

    def literal(m: Any, kinds: tuple[type, ...]) -> bool:
        return get_origin(m) is Literal and any(type(a) in kinds for a in get_args(m))

    number = any(m in (int, float) or literal(m, (int, float)) for m in members)
    return number and not any(m in (bool, Any, object) or literal(m, (bool,)) for m in members)


def bool_for_a_number(tp: Any, value: Any) -> tuple[int | str, ...] | None:
    """Where in ``value`` a true/false stands for a number of type ``tp``: () (the value), (0, 1) (an item), or None."""
    if isinstance(value, bool):
        return () if _number_not_bool(tp) else None
    for m in _members(tp):
        origin, args = get_origin(m), get_args(m)
        if not args:
            continue
        if isinstance(value, dict) and origin is dict:
            items: Any = ((k, args[1], v) for k, v in value.items())
        elif isinstance(value, (list, tuple)) and origin in (tuple, list, set, frozenset, Sequence):
            fixed = origin is tuple and not (len(args) == 2 and args[1] is Ellipsis)
            types = args if fixed else [args[0]] * len(value)
            items = ((k, t, v) for k, (t, v) in enumerate(zip(types, value)))
        else:
            continue
        for key, t, v in items:
            where = bool_for_a_number(t, v)
            if where is not None:
                return (key, *where)
    return None


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


def _listen_host(v: str) -> str:
    if not v.strip() or v != v.strip():
        raise ValueError(
            f"{v!r} is not an address to listen on: give 127.0.0.1 (this PC only), 0.0.0.0 (every address) or one of "
            "this PC's addresses (an empty host would listen on every address without saying so)"
        )
    return v


Finite = Annotated[float, AfterValidator(_finite)]
ListenHost = Annotated[str, AfterValidator(_listen_host)]
"""The address a server of the service listens on: named, never empty (empty would mean every address)."""
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
