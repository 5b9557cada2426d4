"""``cellctl bench accuracy --budget``: the same trials once per error-source setting.

Same seed, so the same postures and draws in every row; per axis, how much the p99 |error| grows
with each source, and the source that adds the most.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
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
from cellctl.cell.cycle_values import CycleCalibration
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


# -- the budget by calibration part, across cells --------------------------------------------------


@dataclass
class PartBudgetCell:
    """One cell's rows of the budget by part: the same trials with each part swapped for the truth."""

    seed: int
    rows: dict[str, Any]  # row key -> CellRun

    def mean(self, key: str) -> dict[str, float]:
        from cellctl.bench.stats import mean_per_axis

        return mean_per_axis(self.rows[key].errors())

    def effect(self, key: str) -> dict[str, float] | None:
        """Axis -> how much the row's swap moves the cell's mean error (None: the row or its reference did not run)."""
        from cellctl.bench.parts import PART_ROWS

        row = next(r for r in PART_ROWS if r.key == key)
        if row.against is None or key not in self.rows or row.against not in self.rows:
            return None
        a, b = self.mean(key), self.mean(row.against)
        return {x: a[x] - b[x] for x in a}


@dataclass
class PartBudget:
    """The budget by calibration part: per cell, each part's effect on the mean error; RMS over cells; dominant part."""

    trials: int
    seeds: list[int]
    keys: list[str]
    cells: list[PartBudgetCell]
    notes: list[str] = field(default_factory=list)

    def effects(self) -> dict[str, dict[str, list[float]]]:
        """Row key -> axis -> the effect in each cell (rows with a reference only)."""
        out: dict[str, dict[str, list[float]]] = {}
        for key in self.keys:
            per = [c.effect(key) for c in self.cells]
            if any(e is None for e in per):
                continue
            out[key] = {a.label: [e[a.label] for e in per if e is not None] for a in AXES}
        return out

    def rms_effects(self) -> dict[str, dict[str, float]]:
        from cellctl.bench.stats import rms

        return {k: {a: rms(v) for a, v in per.items()} for k, per in self.effects().items()}

    def bias_rms(self) -> dict[str, float]:
        """Axis -> RMS over cells of the as-commissioned mean error (the per-cell bias to explain)."""
        from cellctl.bench.stats import rms

        means = [c.mean("as-commissioned") for c in self.cells]
        return {a.label: rms([m[a.label] for m in means]) for a in AXES}

    def dominant(self) -> dict[str, str | None]:
        """Axis -> the part whose swap moves the mean error most (RMS over cells); the oracle row is not a part."""
        from cellctl.bench.parts import PART_ROWS

        parts = {r.key: r.part for r in PART_ROWS if r.part is not None}
        rms_e = {k: v for k, v in self.rms_effects().items() if k in parts}
        out: dict[str, str | None] = {}
        for a in AXES:
            best = max(rms_e, key=lambda k: rms_e[k][a.label] if rms_e[k][a.label] == rms_e[k][a.label] else -1.0, default=None)
            out[a.label] = None if best is None else parts[best]
        return out

    def as_dict(self) -> dict[str, Any]:
        from cellctl.bench.parts import PART_ROWS

        rows = [r for r in PART_ROWS if r.key in self.keys]
        return {
            "benchmark": "accuracy-budget-parts",
            "trials": self.trials,
            "seeds": self.seeds,
            "rows": [{"key": r.key, "part": r.part, "label": r.label, "against": r.against, "chain": r.chain} for r in rows],
            "bias_rms": self.bias_rms(),
            "effect_rms": self.rms_effects(),
            "dominant": self.dominant(),
            "cells": [
                {
                    "seed": c.seed,
                    "mean": {k: c.mean(k) for k in c.rows},
                    "effect": {k: c.effect(k) for k in c.rows if c.effect(k) is not None},
                    "runs": {k: r.as_dict(0) for k, r in c.rows.items()},
                }
                for c in self.cells
            ],
            "notes": self.notes,
        }


def run_part_budget(
    base: CellConfig,
    *,
    seeds: range,
    trials: int,
    time_scale: float | None = None,
    config_source: str = "config/sim.toml",
    devices: DevicesMode = "twin",
    progress: bool = True,
    calibration_cache: Path | None = None,
    keys: tuple[str, ...] | None = None,
    cell_calibration: Callable[[CellConfig, int], CycleCalibration] | None = None,
    cycle_timeout_s: float = 300.0,
) -> PartBudget:
    """Per cell (seed): its calibration from its own data, then the same trials once per row of
    :data:`cellctl.bench.parts.PART_ROWS` (each part swapped for the twin's truth), the loop off.

    ``cell_calibration(config, seed)`` gives a cell's calibration instead of commissioning it (tests).
    """
    from cellctl.bench.cells import AS_CONFIGURED, run_cell, spc_available
    from cellctl.bench.commissioned import commission_cell
    from cellctl.bench.parts import PART_ROWS, FixedCalibrationSource, swapped_calibrations
    from cellctl.bench.progress import Progress
    from cellctl.bench.sources import run_config, run_workdir

    keys = tuple(r.key for r in PART_ROWS) if keys is None else keys
    unknown = sorted(set(keys) - {r.key for r in PART_ROWS})
    if unknown or "as-commissioned" not in keys:
        raise BenchSettingsError(f"budget rows must include as-commissioned and be among {', '.join(r.key for r in PART_ROWS)}; got {keys}")
    if cell_calibration is None and not data_calibration_available():
        raise BenchSettingsError("the budget by part needs the calibration set computed from simulated data (cellctl.calibration.source)")
    loop = "off" if spc_available(base) else AS_CONFIGURED
    notes = [
        "each row runs the same trials (same seed: the same car-body postures) in a fresh service, with the closed loop "
        + ("off" if loop == "off" else "absent from this build"),
        "camera, hand-eye and laser cannot be swapped alone: teaching measured C_Pos_0 and the template through them, "
        "so each is swapped with C_Pos_0, the template and the nine-point map re-taught, and read against the same "
        "re-teaching with the cell's own parts ('re-taught'); see cellctl.bench.parts",
    ]
    say = Progress("budget", 1, enabled=progress)
    cells: list[PartBudgetCell] = []
    with run_workdir(None, "cellctl-bench-parts-") as tmp:
        cache = calibration_cache if calibration_cache is not None else tmp / "calibration-cache"
        for n, seed in enumerate(seeds, 1):
            head = f"cell {n}/{len(seeds)} (seed {seed})"
            config = run_config(base, workdir=tmp / f"cfg-{seed}", seed=seed, calibration="data", time_scale=time_scale, devices=devices)
            if cell_calibration is not None:
                own = cell_calibration(config, seed)
            else:
                say.message(f"{head}: commissioning from its own simulated data ...")
                own = _commissioned_calibration(commission_cell(base, seed, cache, time_scale=time_scale, devices=devices).directory, config)
            say.message(f"{head}: building the swapped calibrations ({', '.join(k for k in keys if k != 'as-commissioned')}) ...")
            cals = swapped_calibrations(own, config, seed, keys)
            rows = {}
            for m, key in enumerate(keys, 1):
                cal = cals[key]
                rows[key] = run_cell(
                    base, seed, trials, loop=loop, calibration="data", calibration_dir=None,
                    source=lambda cal=cal, key=key: FixedCalibrationSource(cal, key), time_scale=time_scale,
                    config_source=config_source, devices=devices, label=f"{head} [{m}/{len(keys)}] {key}",
                    progress=progress, cycle_timeout_s=cycle_timeout_s,
                )  # fmt: skip
            cells.append(PartBudgetCell(seed, rows))
    return PartBudget(trials, list(seeds), list(keys), cells, notes)


def _commissioned_calibration(directory: Path, config: CellConfig) -> CycleCalibration:
    from cellctl.calibration.calibration_set import CalibrationStore
    from cellctl.calibration.source import cycle_calibration_from_set

    cal = CalibrationStore(directory).current()
    if cal is None:
        raise BenchSettingsError(f"no calibration set in {directory}")
    return cycle_calibration_from_set(cal, config.process.align.laser_range_mm)
