"""The paper's experiment (section 5.3) in the simulated cell: N install cycles at random car-body postures.

Every trial goes the way production goes: the composition root builds the service (store, PackML
machine, alarms, orchestrator, the twin's devices, the calibration source), the cell is brought to
Execute, and each cycle is submitted to the orchestrator under an idempotency key, as the PLC link
and the REST API do; a new car body arrives at a random posture for each one. The figures come
from the finished cycle records: ``true_error`` (the twin's six figures of the installed glass
against the true opening) for the accuracy, ``result`` for corrections, shots and cycle time. A
cycle that fails is counted and listed with its reason; the bench then acknowledges the alarm and
brings the cell back to Execute, as an operator would, and goes on.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from cellctl.bench.line_plc import LinePlc, LinePlcError
from cellctl.bench.progress import Progress
from cellctl.bench.sources import (
    BenchSettingsError,
    CalibrationMode,
    DevicesMode,
    data_calibration_available,
    run_config,
    run_workdir,
)
from cellctl.bench.stats import (
    AXES,
    PAPER_TRIALS,
    AxisStats,
    axis_stats,
    percentile,
    within_tolerance_all_axes,
)
from cellctl.cell.orchestrator import CellOrchestrator, CycleRefused
from cellctl.cell.tags import TO_EXECUTE
from cellctl.config import CellConfig
from cellctl.domain import CycleStep, PackMLState
from cellctl.service.compose import Service
from cellctl.service.plc_link import PLC_SCOPE
from cellctl.store import CycleRecord, CycleRequest, CycleState

log = logging.getLogger(__name__)

Outcome = Literal["done", "failed", "refused", "interrupted", "timeout"]

ACTOR = "bench"
# How an operator brings the cell back to Execute from each resting state.
RECOVERY = TO_EXECUTE
SETTLE_TIMEOUT_S = 30.0


class BenchRunError(RuntimeError):
    """The benchmark could not go on (the cell would not calibrate or return to Execute); says why."""


@dataclass(frozen=True)
class Trial:
    """One install cycle of the benchmark, from its record."""

    index: int
    cycle_id: int | None
    outcome: Outcome
    reason: str | None
    true_error: dict[str, float] | None
    cycle_time_s: float | None
    shots: int | None
    correction_mm: list[float] | None
    # The cell's own inspection of the installed glass (absent: the inspection did not run) and the
    # closed loop's state after the cycle (estimate, applied offset, drifting axes, samples).
    measured_deviation: dict[str, float] | None = None
    step_time_s: dict[str, float] | None = None  # seconds on the cell's clock per step
    align: dict[str, Any] | None = None  # how the alignment read the wall (mode, latency on the move)
    spc: dict[str, Any] | None = None
    recipe: str | None = None

    @property
    def installed(self) -> bool:
        return self.outcome == "done" and self.true_error is not None


@dataclass(frozen=True)
class RunSettings:
    """What a run was asked to do."""

    trials: int
    seed: int
    off: tuple[str, ...] = ()
    calibration: CalibrationMode = "oracle"
    time_scale: float | None = None
    config_source: str = "config/sim.toml"
    label: str = ""
    devices: DevicesMode = "twin"
    recipes: Literal["first", "mix"] = "first"  # mix: each trial's recipe drawn (seeded) from the config's recipes
    via: Literal["orchestrator", "plc"] = "orchestrator"  # plc: each cycle requested by a line PLC over Modbus TCP

    def __post_init__(self) -> None:
        if self.trials < 1:
            raise BenchSettingsError(f"--trials must be at least 1, got {self.trials}")
        if self.time_scale is not None and not (0.0 <= self.time_scale <= 10.0):
            raise BenchSettingsError(f"--time-scale must lie in 0..10, got {self.time_scale}")


@dataclass
class AccuracyRun:
    """The outcome of a run: every trial, the per-axis figures and how the run went."""

    settings: RunSettings
    trials: list[Trial]
    axes: list[AxisStats]
    tolerance_mm: float
    tolerance_deg: float
    calibration_summary: dict[str, Any]
    calibration_s: float
    wall_s: float
    recoveries: int
    within_tolerance: int
    workdir: str | None = None
    notes: list[str] = field(default_factory=list)
    recipes: list[str] = field(default_factory=list)  # the configuration's recipes, in its order

    @property
    def installed(self) -> list[Trial]:
        return [t for t in self.trials if t.installed]

    @property
    def not_installed(self) -> list[Trial]:
        return [t for t in self.trials if not t.installed]

    def counts(self) -> dict[str, int]:
        out = {"requested": self.settings.trials, "run": len(self.trials), "installed": len(self.installed)}
        for o in ("failed", "refused", "interrupted", "timeout"):
            out[o] = sum(1 for t in self.trials if t.outcome == o)
        out["within_tolerance_all_axes"] = self.within_tolerance
        return out

    def cycle_time(self) -> dict[str, float]:
        times = [t.cycle_time_s for t in self.installed if t.cycle_time_s is not None]
        shots = [float(t.shots) for t in self.installed if t.shots is not None]
        steps = [t.step_time_s for t in self.installed if t.step_time_s]
        names = sorted({n for st in steps for n in st}, key=lambda n: -percentile([st.get(n, 0.0) for st in steps], 50))
        return {
            "median_s": percentile(times, 50),
            "p95_s": percentile(times, 95),
            "p99_s": percentile(times, 99),
            "median_shots": percentile(shots, 50),
            "max_shots": max(shots) if shots else float("nan"),
            "median_step_s": {n: percentile([st.get(n, 0.0) for st in steps], 50) for n in names},
        }

    def per_recipe(self) -> dict[str, list[AxisStats]]:
        """The per-axis figures of each recipe's installs, when the trials ran more than one recipe."""
        ran = {t.recipe for t in self.trials}
        names = [n for n in self.recipes if n in ran]
        if len(names) < 2:
            return {}
        return {
            n: axis_stats([t.true_error for t in self.installed if t.recipe == n and t.true_error is not None],
                          tolerance_mm=self.tolerance_mm, tolerance_deg=self.tolerance_deg)
            for n in names
        }  # fmt: skip

    def as_dict(self) -> dict[str, Any]:
        return {
            "benchmark": "accuracy",
            "recipes": {n: [s.as_dict() for s in stats] for n, stats in self.per_recipe().items()},
            "settings": {**asdict(self.settings), "off": list(self.settings.off)},
            "tolerance": {"position_mm": self.tolerance_mm, "orientation_deg": self.tolerance_deg},
            "paper": {"trials": PAPER_TRIALS, "max_abs": {a.label: a.paper_max for a in AXES}},
            "axes": [s.as_dict() for s in self.axes],
            "counts": self.counts(),
            "cycle_time": self.cycle_time(),
            "failures": [
                {"trial": t.index, "cycle_id": t.cycle_id, "outcome": t.outcome, "reason": t.reason}
                for t in self.not_installed
            ],
            "calibration": {"summary": self.calibration_summary, "prepare_s": self.calibration_s},
            "recoveries": self.recoveries,
            "wall_s": self.wall_s,
            "workdir": self.workdir,
            "notes": self.notes,
            "trials": [asdict(t) for t in self.trials],
        }


def trial_from_record(index: int, record: CycleRecord) -> Trial:
    """A trial's figures from its finished cycle record."""
    res = dict(record.result or {})
    outcome: Outcome
    if record.state is CycleState.DONE:
        outcome = "done"
    elif record.state is CycleState.FAILED:
        outcome = "failed"
    elif record.state is CycleState.INTERRUPTED:
        outcome = "interrupted"
    else:
        outcome = "timeout"
    reason = record.error if outcome != "timeout" else f"still {record.state.value} in {record.current_step.name.lower()}"
    te = record.true_error
    return Trial(
        index=index,
        cycle_id=record.id,
        outcome=outcome,
        reason=reason,
        true_error=None if te is None else {k: float(v) for k, v in te.items()},
        cycle_time_s=None if res.get("cycle_time_s") is None else float(res["cycle_time_s"]),
        shots=None if res.get("shots") is None else int(res["shots"]),
        correction_mm=None if res.get("correction_mm") is None else [float(v) for v in res["correction_mm"]],
        measured_deviation=_six(res.get("measured_deviation")),
        spc=_jsonable(res["spc"]) if isinstance(res.get("spc"), dict) else None,
        step_time_s=_jsonable(res["step_time_s"]) if isinstance(res.get("step_time_s"), dict) else None,
        align=_align_summary(record),
        recipe=record.request.recipe,
    )


def _align_summary(record: CycleRecord) -> dict[str, Any] | None:
    """The alignment step's reading mode and, on the move, its latency estimate."""
    figures = next((s.figures for s in record.steps if s.step is CycleStep.ALIGN), None)
    if not figures:
        return None
    keys = ("mode", "on_the_fly_unavailable", "spots_along", "stops", "spots_without_reading", "rejected", "readings_fitted",
            "latency_ms", "latency_sigma_ms", "latency", "latency_check")
    return {k: _jsonable(figures[k]) for k in keys if k in figures}


def _six(value: Any) -> dict[str, float] | None:
    """The six figures of a measured deviation, or None when the record has none (or not all six)."""
    if not isinstance(value, dict) or any(a.field not in value or value[a.field] is None for a in AXES):
        return None
    return {a.field: float(value[a.field]) for a in AXES}


class RunHooks:
    """What a caller adds to a run (the multi-cell bench: its calibration, a drift, per-trial probes).

    Every method does nothing here; a subclass overrides what it needs.
    """

    calibration_what: str | None = None  # how the progress line names the run's calibration (None: by its mode)

    def configure(self, config: CellConfig, workdir: Path) -> CellConfig:
        """The run's configuration (already made by run_config), before the service is built."""
        return config

    def attach(self, service: Service) -> None:
        """The service is built and not started yet (e.g. replace its calibration source, subscribe to alarms)."""

    def before_cycle(self, k: int, service: Service) -> None:
        """Trial ``k`` (1-based) is about to be submitted."""

    def after_cycle(self, k: int, service: Service, trial: Trial) -> None:
        """Trial ``k`` finished (or was refused) with ``trial``."""


async def settle(orch: CellOrchestrator, timeout_s: float = SETTLE_TIMEOUT_S) -> PackMLState:
    """Wait until the machine leaves its acting state (Clearing, Resetting, Starting, ...)."""
    deadline = time.monotonic() + timeout_s
    while orch.machine.state.name.endswith("ING") and time.monotonic() < deadline:
        await asyncio.sleep(0.005)
    return orch.machine.state


async def bring_to_execute(orch: CellOrchestrator) -> int:
    """Acknowledge the alarms and send the commands that lead back to Execute; returns commands sent."""
    sent = 0
    for _ in range(4):
        state = await settle(orch)
        if state is PackMLState.EXECUTE:
            return sent
        orch.alarms.acknowledge_all(by=ACTOR)
        plan = RECOVERY.get(state)
        if plan is None:
            raise BenchRunError(f"the cell rests in {state.name} and the bench does not know how to leave it")
        for cmd in plan:
            try:
                await orch.command(cmd, actor=ACTOR, source=ACTOR)
            except Exception as err:  # noqa: BLE001 - the machine's refusal says why
                active = "; ".join(a.summary() for a in orch.alarms.active()) or "none"
                raise BenchRunError(f"{cmd.name} refused in {state.name}: {err} (active alarms: {active})") from err
            sent += 1
            await settle(orch)
    raise BenchRunError(f"the cell did not reach EXECUTE (it is {orch.machine.state.name})")


async def prepare_calibration(service: Service, timeout_s: float) -> float:
    """Make the calibration source ready before the first trial; returns the seconds it took.

    From data: the simulated cell's service commissions itself at start (camera, hand-eye,
    laser, teaching, nine-point as jobs on its own devices, the simulated operator answering);
    this waits for it. From the oracle: teaches in the twin. Either way, the first trial's cycle
    time is then a production cycle's.
    """
    t0 = time.monotonic()
    source = service.orchestrator.calibration
    try:
        await service.ready_for_production(timeout_s)
    except TimeoutError:
        raise BenchRunError(f"the commissioning from simulated data did not finish within {timeout_s:g} s") from None
    except Exception as err:  # noqa: BLE001 - reported with the job's reason
        raise BenchRunError(f"commissioning from simulated data failed: {type(err).__name__}: {err}") from err
    problems = source.problems()
    if problems:
        raise BenchRunError("calibration not ready: " + "; ".join(problems))
    await asyncio.to_thread(source.cycle_calibration)
    return time.monotonic() - t0


async def _run_async(
    config: CellConfig,
    settings: RunSettings,
    workdir: Path,
    progress: Progress,
    cycle_timeout_s: float,
    calibrate_timeout_s: float,
    hooks: RunHooks,
) -> AccuracyRun:
    from cellctl.service import build_service

    t_start = time.monotonic()
    stack = contextlib.AsyncExitStack()
    service = await build_service(config, workdir=workdir)
    hooks.attach(service)
    await service.start()
    trials: list[Trial] = []
    recoveries = 0
    notes: list[str] = []
    try:
        orch = service.orchestrator
        what = hooks.calibration_what or (
            "from simulated data" if settings.calibration == "data" else "from the twin's truth (oracle)"
        )
        progress.message(f"{settings.label or 'run'}: preparing the calibration {what} ...")
        cal_s = await prepare_calibration(service, calibrate_timeout_s)
        summary = dict(orch.calibration.summary())
        await bring_to_execute(orch)
        ids = {name: number for number, name in config.process.recipe_names().items()}
        names = list(ids)
        draw = random.Random(settings.seed)  # the mix of recipes, the same for a seed
        plc = None
        if settings.via == "plc":
            plc = await stack.enter_async_context(LinePlc("127.0.0.1", service.plc_server.port, config.plc.float_word_order,  # type: ignore[attr-defined]
                                                          config.plc.unit_id))  # fmt: skip
        for k in range(1, settings.trials + 1):
            recipe = names[0] if settings.recipes == "first" else draw.choice(names)
            if orch.machine.state is not PackMLState.EXECUTE:
                recoveries += 1
                try:
                    await bring_to_execute(orch)
                except BenchRunError as err:
                    notes.append(f"the run stopped before trial {k}: {err}")
                    break
            request = CycleRequest(recipe, f"bench-{k}", car_id=f"seed{settings.seed}-{k}", source=ACTOR)
            hooks.before_cycle(k, service)
            if plc is None:
                try:
                    sub = await orch.submit_cycle(request, scope=ACTOR, key=f"bench-{settings.seed}-{k}", actor=ACTOR)
                    record: CycleRecord | str = await orch.wait_cycle(sub.cycle.id, cycle_timeout_s)
                except CycleRefused as err:
                    record = err.reason
            else:
                record = await _by_plc(plc, orch, ids[recipe], k, cycle_timeout_s)
            if isinstance(record, str):  # refused: nothing ran
                trials.append(Trial(k, None, "refused", record, None, None, None, None, recipe=recipe))
                hooks.after_cycle(k, service, trials[-1])
                progress.advance("refused")
                continue
            trial = trial_from_record(k, record)
            trials.append(trial)
            hooks.after_cycle(k, service, trial)
            if trial.outcome == "timeout":
                notes.append(f"trial {k}: no result within {cycle_timeout_s:g} s; the run stopped there")
                progress.advance("timeout")
                break
            progress.advance("ok" if trial.installed else f"{trial.outcome}: {(trial.reason or '')[:60]}")
    finally:
        await stack.aclose()
        await service.stop()
    installed = [t.true_error for t in trials if t.installed and t.true_error is not None]
    tol = config.process.tolerance
    return AccuracyRun(
        settings=settings,
        trials=trials,
        axes=axis_stats(installed, tolerance_mm=tol.position_mm, tolerance_deg=tol.orientation_deg),
        tolerance_mm=tol.position_mm,
        tolerance_deg=tol.orientation_deg,
        calibration_summary=_jsonable(summary),
        calibration_s=cal_s,
        wall_s=time.monotonic() - t_start,
        recoveries=recoveries,
        within_tolerance=within_tolerance_all_axes(installed, tolerance_mm=tol.position_mm, tolerance_deg=tol.orientation_deg),
        notes=notes,
        recipes=list(config.process.recipe_names().values()),
    )


async def _by_plc(plc: LinePlc, orch: CellOrchestrator, recipe_id: int, k: int, timeout_s: float) -> CycleRecord | str:
    """Trial ``k`` requested by the line PLC (``cycle_req_id`` = part = k): its record, or why nothing ran."""
    try:
        done = await plc.cycle(recipe_id, k, k, timeout_s)
    except LinePlcError as err:
        return f"the PLC handshake failed: {err}"
    record = await orch.store.cycle_for_key(PLC_SCOPE, str(k))
    return record if record is not None else f"refused over Modbus with error_code {done['error_code']}"


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)


def _workdir(keep: Path | None) -> contextlib.AbstractContextManager[Path]:
    return run_workdir(keep, "cellctl-bench-")


def run_accuracy(
    base: CellConfig,
    settings: RunSettings,
    *,
    progress: bool = True,
    workdir: Path | None = None,
    cycle_timeout_s: float = 300.0,
    calibrate_timeout_s: float = 3600.0,
    hooks: RunHooks | None = None,
) -> AccuracyRun:
    """Run ``settings.trials`` install cycles of the simulated cell and score them against its truth.

    ``workdir`` keeps the run's store, images and calibration set there (default: a temporary
    folder, removed afterwards). ``hooks`` adds to the run what a caller needs (:class:`RunHooks`).
    """
    hooks = hooks if hooks is not None else RunHooks()
    if settings.calibration == "data" and not data_calibration_available():
        raise BenchSettingsError(
            "--calibration data needs the calibration set computed from simulated data "
            "(cellctl.calibration.source), which this installation lacks; use --calibration oracle"
        )
    bar = Progress(settings.label or "accuracy trials", settings.trials, enabled=progress)
    with _workdir(workdir) as wd:
        config = run_config(
            base, workdir=wd, seed=settings.seed, off=settings.off, calibration=settings.calibration,
            time_scale=settings.time_scale, devices=settings.devices,
        )  # fmt: skip
        if settings.via == "plc":  # the cell's Modbus server on a free loopback port, for the bench's PLC
            config = config.model_copy(update={"plc": config.plc.model_copy(update={"enabled": True, "host": "127.0.0.1", "port": 0})})
        config = hooks.configure(config, wd)
        run = asyncio.run(_run_async(config, settings, wd, bar, cycle_timeout_s, calibrate_timeout_s, hooks))
        run.workdir = str(wd) if workdir is not None else None
    return run
