"""``cellctl bench accuracy --budget``: the same trials once per error-source setting.

Same seed, so the same postures and draws in every row; per axis, how much the p99 |error| grows
with each source, and the source that adds the most.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from cellctl.bench.accuracy import AccuracyRun, RunSettings, run_accuracy
from cellctl.bench.sources import (
    CALIBRATION_SOURCE,
    ERROR_SOURCES,
    BenchSettingsError,
    CalibrationMode,
    DevicesMode,
    data_calibration_available,
)
from cellctl.bench.stats import AXES
from cellctl.config import CellConfig

BudgetMode = Literal["alone-on", "alone-off"]


@dataclass(frozen=True)
class BudgetRow:
    """One setting of the budget: which sources are on, and what it gave."""

    label: str
    source: str | None  # the source this row isolates (None: the floor or everything on)
    off: tuple[str, ...]
    calibration: CalibrationMode
    run: AccuracyRun


@dataclass
class Budget:
    """The error budget: one run per setting, and per axis the source that adds the most."""

    mode: BudgetMode
    trials: int
    seed: int
    rows: list[BudgetRow]
    reference: BudgetRow  # alone-on: the floor (all off); alone-off: everything on
    notes: list[str] = field(default_factory=list)

    def shares(self) -> dict[str, dict[str, float]]:
        """Source -> axis -> how much the p99 |error| grows with the source (0 when it does not).

        Alone on: the source's row has it, the reference (the floor) does not. Alone off, and the
        calibration row in either mode: the reference has it, the source's row does not. The
        difference of p99s is what the target is about; it is not additive when sources interact
        (a noisier calibration data set shifts the calibration's bias), so the report shows each
        setting's bias and spread beside it.
        """
        ref = {s.axis: s.p99_abs for s in self.reference.run.axes}
        out: dict[str, dict[str, float]] = {}
        for row in self.rows:
            if row.source is None:
                continue
            p99 = {s.axis: s.p99_abs for s in row.run.axes}
            with_it, without = (p99, ref) if self.mode == "alone-on" and row.source != CALIBRATION_SOURCE else (ref, p99)
            out[row.source] = {a: _grows(with_it[a], without[a]) for a in p99}
        return out

    def dominant(self) -> dict[str, str | None]:
        """Axis -> the source whose share is largest (None when no source adds anything)."""
        shares = self.shares()
        out: dict[str, str | None] = {}
        for a in AXES:
            best = max(shares, key=lambda s: shares[s][a.label], default=None)
            out[a.label] = best if best is not None and shares[best][a.label] > 0 else None
        return out

    def as_dict(self) -> dict[str, Any]:
        return {
            "benchmark": "accuracy-budget",
            "mode": self.mode,
            "trials": self.trials,
            "seed": self.seed,
            "rows": [
                {
                    "label": r.label,
                    "source": r.source,
                    "off": list(r.off),
                    "calibration": r.calibration,
                    "axes": [s.as_dict() for s in r.run.axes],
                    "counts": r.run.counts(),
                    "failures": [
                        {"trial": t.index, "outcome": t.outcome, "reason": t.reason} for t in r.run.not_installed
                    ],
                }
                for r in self.rows
            ],
            "reference": self.reference.label,
            "p99_added": self.shares(),
            "dominant": self.dominant(),
            "notes": self.notes,
        }


PlanRow = tuple[str, str | None, tuple[str, ...], CalibrationMode]


def _grows(with_it: float, without: float) -> float:
    d = with_it - without
    return float(d) if d > 0 else 0.0


def budget_plan(mode: BudgetMode, calibration: CalibrationMode, *, data_available: bool) -> list[PlanRow]:
    """The settings of a budget: (label, isolated source, sources off, calibration).

    Every row uses ``calibration``, so a source also acts through the calibration data it spoils.
    With ``"data"``, one more row runs on the true calibrations: the difference is the
    calibrations' own share. Sources that act only through the calibration from data (the
    operator's hand guiding in teaching) are left out with the oracle.
    """
    if mode not in ("alone-on", "alone-off"):
        raise BenchSettingsError(f"--budget must be alone-on or alone-off, got {mode!r}")
    if calibration == "data" and not data_available:
        raise BenchSettingsError("a budget with --calibration data needs cellctl.calibration.source; use --calibration oracle")
    every = tuple(s for s in ERROR_SOURCES if calibration == "data" or not ERROR_SOURCES[s].data_calibration_only)
    cal_word = "calibration from data" if calibration == "data" else "true calibrations"
    plan: list[PlanRow] = []
    if mode == "alone-on":
        plan.append((f"none (floor), {cal_word}", None, tuple(ERROR_SOURCES), calibration))
        for s in every:
            plan.append((f"{s} alone", s, tuple(x for x in ERROR_SOURCES if x != s), calibration))
        if calibration == "data":
            plan.append(("none, true calibrations", CALIBRATION_SOURCE, tuple(ERROR_SOURCES), "oracle"))
        plan.append((f"all on, {cal_word}", None, (), calibration))
    else:
        plan.append((f"all on, {cal_word}", None, (), calibration))
        for s in every:
            plan.append((f"all but {s}", s, (s,), calibration))
        if calibration == "data":
            plan.append(("all on, true calibrations", CALIBRATION_SOURCE, (), "oracle"))
    return plan


def run_budget(
    base: CellConfig,
    *,
    mode: BudgetMode,
    trials: int,
    seed: int,
    calibration: CalibrationMode,
    time_scale: float | None = None,
    config_source: str = "config/sim.toml",
    devices: DevicesMode = "twin",
    progress: bool = True,
    cycle_timeout_s: float = 300.0,
) -> Budget:
    """The same ``trials`` (same seed) once per source setting; see :func:`budget_plan`."""
    plan = budget_plan(mode, calibration, data_available=data_calibration_available())
    notes = []
    if calibration == "oracle":
        notes.append(
            "true calibrations (oracle) in every row: the calibrations' share and the teaching hand-guiding error "
            "are not in this budget (use --calibration data)"
        )
    rows = []
    for n, (label, source, off, cal) in enumerate(plan, 1):
        settings = RunSettings(
            trials, seed, off, cal, time_scale, config_source, label=f"[{n}/{len(plan)}] {label}", devices=devices
        )
        run = run_accuracy(base, settings, progress=progress, cycle_timeout_s=cycle_timeout_s)
        rows.append(BudgetRow(label, source, off, cal, run))
    # alone-on: the floor (everything off); alone-off: everything on. Both are the plan's first row.
    return Budget(mode, trials, seed, rows, rows[0], notes)
