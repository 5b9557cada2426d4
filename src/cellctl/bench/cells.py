"""``cellctl bench accuracy --cells N``: N simulated cells, each commissioned from its own simulated data.

A line integrator commissions many cells; a figure met on one cell (one seed) is not met. Each cell
(seed S, S+1, ...) is first commissioned by the simulated cell's service from its own simulated data
(camera, hand-eye, laser, teaching, nine-point as jobs, the simulated operator answering: exactly
what ``--calibration data`` does in one run) and its calibration set is kept; then the cell runs
``trials`` install cycles through the orchestrator, once per loop setting (``--loop both``: the
closed loop off, then on), each run in a fresh service of the same seed with that same calibration
set, so both runs see the same car-body postures and the same calibration. The figures come from
the cycle records: the twin's truth (``true_error``), the cell's own inspection
(``result["measured_deviation"]``) and the loop's state (``result["spc"]``).

A drift (:mod:`cellctl.bench.drift`) turns the twin's camera mount mid-run; per cell the report
gives the cycle at which the drift alarm was first raised and the first cycle whose true error
left the tolerance.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from cellctl.bench.accuracy import (
    AccuracyRun,
    BenchRunError,
    RunHooks,
    RunSettings,
    Trial,
    run_accuracy,
)
from cellctl.bench.commissioned import commission_cell, copy_set
from cellctl.bench.drift import DriftInjector, DriftSpec
from cellctl.bench.progress import Progress
from cellctl.bench.sources import (
    BenchSettingsError,
    CalibrationMode,
    DevicesMode,
    run_workdir,
)
from cellctl.bench.stats import (
    AXES,
    CELLS_TARGET_P99,
    MEASUREMENT_TARGET_P99,
    SETTLED_MEAN_BAR,
    AxisStats,
    axes_outside,
    axis_stats,
    difference,
    mean_per_axis,
)
from cellctl.config import CellConfig

LoopMode = Literal["on", "off", "both"]
LOOP_MODES: tuple[LoopMode, ...] = ("on", "off", "both")
AS_CONFIGURED = "as configured"
DRIFT_ALARM = "SPC_DRIFT"


def drift_alarm_code() -> Any:
    """The drift alarm's code (``AlarmCode.SPC_DRIFT``), or None when this build has none."""
    from cellctl.domain import AlarmCode

    return getattr(AlarmCode, DRIFT_ALARM, None)


def spc_available(config: CellConfig) -> bool:
    """Whether this build has the closed loop (``[process.spc]``)."""
    return getattr(config.process, "spc", None) is not None


def with_loop(config: CellConfig, enabled: bool) -> CellConfig:
    """``config`` with ``process.spc.enabled`` set (the loop's other settings kept)."""
    spc = getattr(config.process, "spc", None)
    if spc is None:
        raise BenchSettingsError("this build has no closed loop (process.spc): --loop cannot switch it")
    process = config.process.model_copy(update={"spc": spc.model_copy(update={"enabled": enabled})})
    return config.model_copy(update={"process": process})


def loop_variants(config: CellConfig, loop: LoopMode) -> tuple[list[str], list[str]]:
    """The runs per cell (``off``, ``on``, or ``as configured`` without a loop in this build) and notes."""
    if loop not in LOOP_MODES:
        raise BenchSettingsError(f"--loop must be one of {', '.join(LOOP_MODES)}, got {loop!r}")
    if not spc_available(config):
        return [AS_CONFIGURED], [
            "this build has no closed loop (process.spc is missing): each cell runs once as configured, "
            f"--loop {loop} has nothing to switch"
        ]
    return (["off", "on"] if loop == "both" else [loop]), []


@dataclass(frozen=True)
class CellsSettings:
    """What a multi-cell run was asked to do."""

    cells: int
    trials: int
    seed: int
    loop: LoopMode = "on"
    settle: int = 20
    calibration: CalibrationMode = "data"
    off: tuple[str, ...] = ()
    time_scale: float | None = None
    config_source: str = "config/sim.toml"
    devices: DevicesMode = "twin"
    drift: DriftSpec | None = None

    def __post_init__(self) -> None:
        if self.cells < 1:
            raise BenchSettingsError(f"--cells must be at least 1, got {self.cells}")
        if self.trials < 1:
            raise BenchSettingsError(f"--trials must be at least 1, got {self.trials}")
        if self.settle < 0:
            raise BenchSettingsError(f"--settle must be 0 or more cycles, got {self.settle}")

    @property
    def seeds(self) -> range:
        return range(self.seed, self.seed + self.cells)


# -- one cell's run -------------------------------------------------------------------------------


class CellHooks(RunHooks):
    """One cell's run: its calibration set (or a fixed calibration), the loop switch, the drift, the probes.

    Args:
        calibration_dir: the cell's commissioned set, copied into the run (None: the run's own source).
        loop: switch the closed loop on or off (None: as configured).
        drift: the drift to inject (None: none).
        source: builds the calibration source the orchestrator uses instead (the budget's rows).
    """

    def __init__(
        self,
        calibration_dir: Path | None,
        loop: bool | None,
        drift: DriftSpec | None,
        source: Callable[[], Any] | None = None,
    ) -> None:
        self.calibration_dir = calibration_dir
        self.loop = loop
        self.drift = drift
        self.source = source
        self.injector: DriftInjector | None = None
        self.twin: Any = None
        if source is not None:
            self.calibration_what = "(a fixed calibration handed to every cycle)"
        elif calibration_dir is not None:
            self.calibration_what = f"from the cell's commissioned set ({calibration_dir})"
        self.cycle = 0
        self.probes: list[dict[str, Any]] = []
        self.alarms: list[dict[str, Any]] = []

    def configure(self, config: CellConfig, workdir: Path) -> CellConfig:
        if self.calibration_dir is not None or self.source is not None:
            cal = config.calibration.model_copy(update={"auto_calibrate_in_sim": False})
            config = config.model_copy(update={"calibration": cal})
        if self.calibration_dir is not None:
            copy_set(self.calibration_dir, Path(config.calibration.directory))
        if self.loop is not None:
            config = with_loop(config, self.loop)
        return config

    def attach(self, service: Any) -> None:
        twin = service.extras.get("twin")
        if twin is None:
            raise BenchRunError("the service has no twin (service.extras['twin']): the multi-cell bench needs the simulated cell")
        self.twin = twin
        self.injector = DriftInjector(self.drift, twin.cell)
        if self.source is not None:
            service.orchestrator.calibration = self.source()
        service.orchestrator.alarms.subscribe(self._alarm)

    def _alarm(self, event: Any) -> None:
        if getattr(event.kind, "value", None) != "raised":
            return
        a = event.alarm
        self.alarms.append({"cycle": self.cycle, "code": int(a.code), "name": getattr(a.code, "name", str(a.code)), "message": a.message})

    def before_cycle(self, k: int, service: Any) -> None:
        self.cycle = k
        assert self.injector is not None
        mount = self.injector.before_cycle(k)
        self.probes.append({"trial": k, "camera_mount_deg": mount, "drift_deg": 0.0 if self.drift is None else self.drift.angle_at(k)})

    def after_cycle(self, k: int, service: Any, trial: Trial) -> None:
        self.probes[-1]["T_B_T"] = self.twin.cell.world().T_B_T.tolist()


@dataclass
class CellRun:
    """One cell's trials under one loop setting, with the probes and the alarms raised."""

    seed: int
    loop: str
    run: AccuracyRun
    probes: list[dict[str, Any]]
    alarms: list[dict[str, Any]]
    commissioning: dict[str, Any]

    def errors(self) -> list[dict[str, float]]:
        return [t.true_error for t in self.run.installed if t.true_error is not None]

    def axes(self) -> list[AxisStats]:
        tol = self.run
        return axis_stats(self.errors(), tolerance_mm=tol.tolerance_mm, tolerance_deg=tol.tolerance_deg, targets=CELLS_TARGET_P99)

    def settled_mean(self, settle: int) -> dict[str, float]:
        """Axis -> the mean true error of the installs after the first ``settle`` cycles (NaN: none left)."""
        return mean_per_axis([t.true_error for t in self.run.installed if t.index > settle and t.true_error is not None])

    def measurement_errors(self) -> list[dict[str, float]]:
        """Measured minus true deviation, for every install the cell inspected."""
        return [difference(t.measured_deviation, t.true_error) for t in self.run.installed if t.measured_deviation and t.true_error]

    def inspected(self) -> int:
        return sum(1 for t in self.run.installed if t.measured_deviation is not None)

    def first_out_of_tolerance(self) -> tuple[int, list[str]] | None:
        """The first cycle whose true error left the tolerance, and the axes outside (None: none did)."""
        for t in self.run.trials:
            if t.true_error is None:
                continue
            out = axes_outside(t.true_error, tolerance_mm=self.run.tolerance_mm, tolerance_deg=self.run.tolerance_deg)
            if out:
                return t.index, out
        return None

    def drift_alarm(self) -> dict[str, Any] | None:
        """The first drift alarm raised (its cycle and message), None when none was."""
        return next((a for a in self.alarms if a["name"] == DRIFT_ALARM), None)

    def loop_state(self) -> dict[str, Any] | None:
        """The loop's state after the last cycle that reported one (``result["spc"]``), None: none did."""
        return next((t.spc for t in reversed(self.run.trials) if t.spc), None)

    def as_dict(self, settle: int) -> dict[str, Any]:
        first = self.first_out_of_tolerance()
        meas = self.measurement_errors()
        trials = []
        for t, p in zip(self.run.trials, self.probes):
            trials.append({**asdict(t), **{k: v for k, v in p.items() if k != "trial"}})
        return {
            "seed": self.seed,
            "loop": self.loop,
            "counts": self.run.counts(),
            "axes": [a.as_dict() for a in self.axes()],
            "settled_mean": self.settled_mean(settle),
            "inspected": self.inspected(),
            "measurement_error_p99": _p99(meas) if meas else None,
            "first_out_of_tolerance": None if first is None else {"cycle": first[0], "axes": first[1]},
            "drift_alarm": self.drift_alarm(),
            "loop_state": self.loop_state(),
            "alarms": self.alarms,
            "commissioning": self.commissioning,
            "wall_s": self.run.wall_s,
            "notes": self.run.notes,
            "trials": trials,
        }


def _p99(errors: list[dict[str, float]]) -> dict[str, float]:
    import numpy as np

    return {a.label: float(np.percentile([abs(e[a.field]) for e in errors], 99)) for a in AXES}


def run_cell(
    base: CellConfig,
    seed: int,
    trials: int,
    *,
    loop: str,
    calibration: CalibrationMode,
    calibration_dir: Path | None,
    drift: DriftSpec | None = None,
    source: Callable[[], Any] | None = None,
    off: tuple[str, ...] = (),
    time_scale: float | None = None,
    config_source: str = "config/sim.toml",
    devices: DevicesMode = "twin",
    label: str = "",
    progress: bool = True,
    cycle_timeout_s: float = 300.0,
    commissioning: dict[str, Any] | None = None,
) -> CellRun:
    """One cell's ``trials`` cycles under ``loop`` (``on``, ``off`` or ``as configured``)."""
    hooks = CellHooks(calibration_dir, None if loop == AS_CONFIGURED else loop == "on", drift, source)
    settings = RunSettings(trials, seed, off, calibration, time_scale, config_source, label=label, devices=devices)
    run = run_accuracy(base, settings, progress=progress, cycle_timeout_s=cycle_timeout_s, hooks=hooks)
    return CellRun(seed, loop, run, hooks.probes, hooks.alarms, commissioning or {})


# -- the whole run -----------------------------------------------------------------------------------


@dataclass
class CellsRun:
    """Every cell under every loop setting: ``cells[i][loop]``."""

    settings: CellsSettings
    loops: list[str]
    cells: list[dict[str, CellRun]]
    tolerance_mm: float
    tolerance_deg: float
    wall_s: float
    notes: list[str] = field(default_factory=list)

    def runs(self, loop: str) -> list[CellRun]:
        return [c[loop] for c in self.cells if loop in c]

    def pooled(self, loop: str) -> list[AxisStats]:
        """Per-axis figures over the concatenation of every cell's installs."""
        errors = [e for r in self.runs(loop) for e in r.errors()]
        return axis_stats(errors, tolerance_mm=self.tolerance_mm, tolerance_deg=self.tolerance_deg, targets=CELLS_TARGET_P99)

    def measurement(self, loop: str) -> tuple[int, dict[str, float] | None]:
        """How many installs were inspected, and the inspection's error p99 per axis over all cells (None: none)."""
        errors = [e for r in self.runs(loop) for e in r.measurement_errors()]
        return len(errors), (_p99(errors) if errors else None)

    def bars(self) -> dict[str, bool | None]:
        """The issue's bars on the loop that counts (on, else the only one run); None: not measured."""
        loop = "on" if "on" in self.loops else self.loops[0]
        pooled = self.pooled(loop)
        settled = [m for m in (r.settled_mean(self.settings.settle) for r in self.runs(loop)) if m["X"] == m["X"]]
        n, p99 = self.measurement(loop)
        return {
            "loop": loop,  # type: ignore[dict-item]
            "pooled_p99": all(a.p99_met for a in pooled) if pooled and pooled[0].n else None,
            "settled_mean": (
                all(all(abs(m[a.label]) <= SETTLED_MEAN_BAR["mm"] for a in AXES if a.unit == "mm") for m in settled)
                if settled else None
            ),
            "inspection_p99": None if p99 is None else all(p99[a.label] <= MEASUREMENT_TARGET_P99[a.unit] for a in AXES),
        }

    def met(self) -> bool:
        return all(v is not False for k, v in self.bars().items() if k != "loop")

    def as_dict(self) -> dict[str, Any]:
        s = self.settings
        out: dict[str, Any] = {
            "bars": self.bars(),
            "benchmark": "accuracy-cells",
            "settings": {
                "cells": s.cells, "trials": s.trials, "seeds": list(s.seeds), "loop": s.loop, "settle": s.settle,
                "calibration": s.calibration, "off": list(s.off), "time_scale": s.time_scale, "config": s.config_source,
                "devices": s.devices, "drift": None if s.drift is None else s.drift.as_dict(),
            },  # fmt: skip
            "tolerance": {"position_mm": self.tolerance_mm, "orientation_deg": self.tolerance_deg},
            "loops": self.loops,
            "pooled": {},
            "measurement_error": {},
            "cells": [{loop: r.as_dict(s.settle) for loop, r in c.items()} for c in self.cells],
            "wall_s": self.wall_s,
            "notes": self.notes,
        }
        for loop in self.loops:
            out["pooled"][loop] = [a.as_dict() for a in self.pooled(loop)]
            n, p99 = self.measurement(loop)
            out["measurement_error"][loop] = {"inspected": n, "p99_abs": p99}
        return out


def run_cells(
    base: CellConfig,
    settings: CellsSettings,
    *,
    progress: bool = True,
    calibration_cache: Path | None = None,
    cycle_timeout_s: float = 300.0,
) -> CellsRun:
    """Every cell of ``settings``: commissioned once from its own data, then its trials under each loop setting."""
    loops, notes = loop_variants(base, settings.loop)
    if getattr(getattr(base.process, "inspect", None), "enabled", None) is False:
        notes.append("the post-install inspection is off (process.inspect.enabled = false): no measured deviation, "
                     "and the loop has nothing to estimate from")  # fmt: skip
    if settings.drift is not None:
        notes.append(settings.drift.describe())
    if settings.calibration == "oracle":
        notes.append("calibration: the twin's true mountings (oracle) in every cell, not each cell's own data")
    say = Progress("cells", 1, enabled=progress)
    t0 = time.monotonic()
    cells: list[dict[str, CellRun]] = []
    with run_workdir(None, "cellctl-bench-cells-") as tmp:
        cache = calibration_cache if calibration_cache is not None else tmp / "calibration-cache"
        for n, seed in enumerate(settings.seeds, 1):
            head = f"cell {n}/{settings.cells} (seed {seed})"
            directory: Path | None = None
            comm: dict[str, Any] = {"calibration": settings.calibration}
            if settings.calibration == "data":
                say.message(f"{head}: commissioning from its own simulated data ...")
                c = commission_cell(base, seed, cache, off=settings.off, time_scale=settings.time_scale, devices=settings.devices)
                directory = c.directory
                comm.update(seconds=c.seconds, cached=c.cached, cache=str(c.directory))
                say.message(f"{head}: calibration set " + ("taken from the cache" if c.cached else f"commissioned in {c.seconds:.0f} s"))
            runs: dict[str, CellRun] = {}
            for loop in loops:
                runs[loop] = run_cell(
                    base, seed, settings.trials, loop=loop, calibration=settings.calibration, calibration_dir=directory,
                    drift=settings.drift, off=settings.off, time_scale=settings.time_scale,
                    config_source=settings.config_source, devices=settings.devices, label=f"{head} loop {loop}",
                    progress=progress, cycle_timeout_s=cycle_timeout_s, commissioning=comm,
                )  # fmt: skip
            cells.append(runs)
    tol = base.process.tolerance
    return CellsRun(settings, loops, cells, tol.position_mm, tol.orientation_deg, time.monotonic() - t0, notes)
