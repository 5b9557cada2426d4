"""The values of the closed loop (:mod:`cellctl.quality.spc`): its state, what an update changed, the
history entry it leaves, and the state's JSON form (what the store keeps across a restart).

Axes are the six figures of :class:`cellctl.domain.InstallDeviation` (``dx_mm`` ... ``drz_deg``):
millimetres for x, y, z, degrees for rx, ry, rz.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Literal

from cellctl.domain import DEVIATION_KEYS

__all__ = [
    "AXES", "AxisState", "Drift", "DriftKind", "Exclusion", "SpcEvent", "SpcRecord", "SpcState", "SpcUpdate",
    "axis_unit", "state_from_dict", "state_to_dict",
]

AXES: tuple[str, ...] = DEVIATION_KEYS
"""``dx_mm, dy_mm, dz_mm, drx_deg, dry_deg, drz_deg``."""

STATE_FORMAT = 1
"""The version of :func:`state_to_dict`'s layout; :func:`state_from_dict` refuses any other."""


def axis_unit(axis: str) -> Literal["mm", "deg"]:
    """The unit of an axis, from its name."""
    if axis not in AXES:
        raise ValueError(f"unknown axis {axis!r}; the axes are {', '.join(AXES)}")
    return "mm" if axis.endswith("_mm") else "deg"


class Exclusion(str, enum.Enum):
    """Why a result did not feed the loop."""

    NOT_INSTALLED = "not_installed"  # no measurement: the cycle failed or did not install
    UNRELIABLE = "unreliable"  # the measurement flagged itself unreliable
    NOT_FINITE = "not_finite"  # a figure is NaN or infinite
    BEYOND_TOLERANCE = "beyond_tolerance"  # the install is out of tolerance: a reject, not a sample
    OUTLIER = "outlier"  # further than outlier_k robust sigmas from the estimate
    DUPLICATE = "duplicate"  # this cycle already fed the loop (nothing changed, nothing to save)


class SpcEvent(str, enum.Enum):
    """What an update reports beside the figures."""

    RESET_CALIBRATION = "reset_calibration"  # the calibration it learns under changed (its recipe's parts)
    RESET_OPERATOR = "reset_operator"  # an explicit reset
    ESTIMATE_STARTED = "estimate_started"  # min_samples results since the reset: the estimate runs
    DRIFT = "drift"  # an axis started drifting (see :class:`Drift`)


class DriftKind(str, enum.Enum):
    TREND = "trend"  # the estimate passed the drift limit
    STEP = "step"  # outlier_run results in a row excluded on one side: the cell jumped


@dataclass(frozen=True)
class Drift:
    """An axis that drifts: recalibrate (``cellctl calibrate verify``, then the procedure it names).

    ``value`` is the estimate (trend) or the last uncompensated deviation (step), ``limit`` the
    axis's drift limit, ``gate`` (a step) how far the results were admitted (the outlier gate about the
    estimate, or the install tolerance about 0), ``tested`` (a step) what the gate refused in the last of
    them (its distance from the estimate, or the measured deviation), all in the axis's unit.
    """

    axis: str
    kind: DriftKind
    value: float
    limit: float
    gate: float | None = None
    tested: float | None = None


@dataclass(frozen=True)
class AxisState:
    """One axis: the estimate (None until min_samples), its robust sigma, the offset it applies, the
    results gathered before the estimate starts, and the run of gate failures (+ above, - below)."""

    estimate: float | None = None
    sigma: float | None = None
    offset: float = 0.0
    warmup: tuple[float, ...] = ()
    run: int = 0

    @property
    def warm_up_mean(self) -> float | None:
        """The mean of the results gathered before the estimate starts (None when there are none)."""
        return sum(self.warmup) / len(self.warmup) if self.warmup else None


def _fresh_axes() -> dict[str, AxisState]:
    return {a: AxisState() for a in AXES}


@dataclass(frozen=True)
class SpcState:
    """The loop after its last update. ``n_samples`` and ``excluded`` (by :class:`Exclusion` value)
    count since the last reset; ``drifting`` stays until a reset (a recalibration resets)."""

    calibration_version: str | None = None
    axes: Mapping[str, AxisState] = field(default_factory=_fresh_axes)
    n_samples: int = 0
    excluded: Mapping[str, int] = field(default_factory=dict)
    drifting: tuple[Drift, ...] = ()
    last_cycle_id: int | None = None
    updated_at: datetime | None = None
    reset_at: datetime | None = None
    reset_reason: SpcEvent | None = None

    def __post_init__(self) -> None:
        if set(self.axes) != set(AXES):
            raise ValueError(f"an SPC state needs the axes {', '.join(AXES)}, got {', '.join(self.axes)}")

    @property
    def estimating(self) -> bool:
        """Whether the estimate runs (min_samples results since the last reset)."""
        return all(s.estimate is not None for s in self.axes.values())

    @property
    def estimate(self) -> dict[str, float | None]:
        return {a: self.axes[a].estimate for a in AXES}

    @property
    def offset(self) -> dict[str, float]:
        """The offset decided at the last update (what :meth:`SpcLoop.offset` gives under the same config)."""
        return {a: self.axes[a].offset for a in AXES}

    @property
    def n_excluded(self) -> int:
        return sum(self.excluded.values())

    @property
    def drifting_axes(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(d.axis for d in self.drifting))


@dataclass(frozen=True)
class SpcRecord:
    """One history entry: what the store keeps per update (see :meth:`as_entry`)."""

    cycle_id: int | None
    calibration_version: str | None
    events: tuple[SpcEvent, ...]
    excluded: Exclusion | None
    u: Mapping[str, float] | None  # the uncompensated deviation (measured + applied offset)
    estimate: Mapping[str, float | None]
    offset: Mapping[str, float]  # for the next install
    drifting: tuple[str, ...]

    def as_entry(self) -> dict[str, Any]:
        """Plain values for :meth:`cellctl.store.db.CellStore.save_spc`'s ``entry``."""
        return {
            "cycle_id": self.cycle_id,
            "calibration_version": self.calibration_version,
            "events": [e.value for e in self.events],
            "excluded": None if self.excluded is None else self.excluded.value,
            "u": None if self.u is None else dict(self.u),
            "estimate": dict(self.estimate),
            "offset": dict(self.offset),
            "drifting": list(self.drifting),
        }


@dataclass(frozen=True)
class SpcUpdate:
    """An update's result: the new state, its history entry (None: nothing happened, save nothing),
    and what changed (the offset for the next install against ``previous_offset``, the one this
    install used; drift that started; a reset; why the result was excluded)."""

    state: SpcState
    record: SpcRecord | None
    previous_offset: Mapping[str, float]
    excluded: Exclusion | None = None
    drift_started: tuple[Drift, ...] = ()
    reset: SpcEvent | None = None

    @property
    def offset_changed(self) -> bool:
        return any(self.previous_offset[a] != self.state.offset[a] for a in AXES)

    @property
    def events(self) -> tuple[SpcEvent, ...]:
        return () if self.record is None else self.record.events


# -- JSON form --------------------------------------------------------------------------------------


def state_to_dict(state: SpcState) -> dict[str, Any]:
    """The state as plain JSON values (what :meth:`cellctl.store.db.CellStore.save_spc` keeps)."""
    return {
        "format": STATE_FORMAT,
        "calibration_version": state.calibration_version,
        "axes": {
            a: {"estimate": s.estimate, "sigma": s.sigma, "offset": s.offset, "warmup": list(s.warmup), "run": s.run}
            for a, s in state.axes.items()
        },
        "n_samples": state.n_samples,
        "excluded": dict(state.excluded),
        "drifting": [
            {"axis": d.axis, "kind": d.kind.value, "value": d.value, "limit": d.limit, "gate": d.gate, "tested": d.tested}
            for d in state.drifting
        ],
        "last_cycle_id": state.last_cycle_id,
        "updated_at": None if state.updated_at is None else state.updated_at.isoformat(),
        "reset_at": None if state.reset_at is None else state.reset_at.isoformat(),
        "reset_reason": None if state.reset_reason is None else state.reset_reason.value,
    }


def _num(what: str, v: Any, *, optional: bool = False) -> float | None:
    if v is None and optional:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"stored SPC state: {what} must be a finite number, got {v!r}")
    return float(v)


def _req(what: str, v: Any) -> float:
    x = _num(what, v)
    assert x is not None
    return x


def state_from_dict(d: Mapping[str, Any]) -> SpcState:
    """:func:`state_to_dict` back; a ValueError names what is wrong (start afresh and say so)."""
    if d.get("format") != STATE_FORMAT:
        raise ValueError(f"stored SPC state has format {d.get('format')!r}, this cellctl reads {STATE_FORMAT}")
    try:
        axes = {}
        for a in AXES:
            s = d["axes"][a]
            axes[a] = AxisState(
                estimate=_num(f"{a} estimate", s["estimate"], optional=True),
                sigma=_num(f"{a} sigma", s["sigma"], optional=True),
                offset=_req(f"{a} offset", s["offset"]),
                warmup=tuple(_req(f"{a} warm-up", x) for x in s["warmup"]),
                run=int(s["run"]),
            )
        version = d["calibration_version"]
        return SpcState(
            calibration_version=None if version is None else str(version),
            axes=axes,
            n_samples=int(d["n_samples"]),
            excluded={Exclusion(k).value: int(v) for k, v in d["excluded"].items()},
            drifting=tuple(
                Drift(
                    x["axis"], DriftKind(x["kind"]), float(x["value"]), float(x["limit"]),
                    _num("a step's gate", x.get("gate"), optional=True),
                    _num("what a step's gate refused", x.get("tested"), optional=True),
                )  # fmt: skip
                for x in d["drifting"]
            ),
            last_cycle_id=None if d["last_cycle_id"] is None else int(d["last_cycle_id"]),
            updated_at=None if d["updated_at"] is None else datetime.fromisoformat(d["updated_at"]),
            reset_at=None if d["reset_at"] is None else datetime.fromisoformat(d["reset_at"]),
            reset_reason=None if d["reset_reason"] is None else SpcEvent(d["reset_reason"]),
        )
    except (KeyError, TypeError, AttributeError) as err:
        raise ValueError(f"stored SPC state is incomplete or malformed: {err!r}") from None
