"""``cellctl bench cycle-time``: stop and go against reading the wall on the move, on the same cells.

Each cell (one twin per seed) runs ``trials`` install cycles through the orchestrator with
``process.align.mode = "stop_and_go"``, with ``"on_the_fly"``, and on the move again with the
latency not estimated but taken 10 ms off the twin's (what leaving it uncompensated costs); the
same seed each time (so the same car-body postures and error sources) and the twin's own devices,
which can store laser readings and stream the robot's pose. The cycle time is the record's, on the cell's clock: the
robot time a real cell would take, and where it goes (the twin's time line's ledger around each cycle:
moves by speed, turns, the laser's read-out, frames, the gripper; the rest is the cell's own computing).
The accuracy is the true install error per axis.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from cellctl.bench.accuracy import AccuracyRun, RunHooks, RunSettings, Trial, run_accuracy
from cellctl.bench.stats import AXES, normal_p99_abs, p99_difference_interval, percentile
from cellctl.config import CellConfig
from cellctl.geometry.motion import TrapezoidProfile
from cellctl.service.compose import Service

AlignMode = Literal["stop_and_go", "on_the_fly"]
# The bar: on the move takes at most half the stop-and-go time, its p99 no worse by more than these.
TIME_RATIO_BAR = 0.5
LATENCY_ERROR_S = 0.010  # the third run pairs with the twin's latency off by this much: what not estimating it costs
UNCOMPENSATED = "on_the_fly, latency 10 ms off"
P99_SLACK = {"mm": 0.01, "deg": 0.005}


def with_align_mode(config: CellConfig, mode: AlignMode, **sweep: Any) -> CellConfig:
    """``config`` with ``process.align.mode`` set (and ``process.align.sweep`` fields, if given)."""
    align = config.process.align
    update: dict[str, Any] = {"mode": mode} | ({"sweep": align.sweep.model_copy(update=sweep)} if sweep else {})
    process = config.process.model_copy(update={"align": align.model_copy(update=update)})
    return config.model_copy(update={"process": process})


COMPUTING = "the rest: the cell's own computing and waits"


class SpentPerCycle(RunHooks):
    """What each cycle's time on the twin's time line was spent on (simulated seconds, by ledger entry)."""

    def __init__(self) -> None:
        self.by_trial: dict[int, dict[str, float]] = {}
        self._before: dict[str, float] = {}

    @staticmethod
    def _ledger(service: Service) -> dict[str, float]:
        return service.extras["twin"].cell.timeline.spent()  # a copy

    def before_cycle(self, k: int, service: Service) -> None:
        self._before = self._ledger(service)

    def after_cycle(self, k: int, service: Service, trial: Trial) -> None:
        after = self._ledger(service)
        spent = {n: s - self._before.get(n, 0.0) for n, s in after.items() if abs(s - self._before.get(n, 0.0)) > 1e-9}
        if trial.cycle_time_s is not None:
            spent[COMPUTING] = trial.cycle_time_s - sum(spent.values())
        self.by_trial[k] = spent


@dataclass(frozen=True)
class ModeFigures:
    """One mode's cycles over every cell."""

    mode: str
    installed: int
    requested: int
    cycle_s: list[float]
    step_s: list[dict[str, float]]
    errors: np.ndarray  # (n, 6) true install errors in AXES order
    on_the_fly: int  # cycles whose alignment really read on the move
    latency_ms: list[float]
    latency_modes: dict[str, int]  # how the sweeps had the latency: timed, checked, fixed
    estimated_ms: list[float]  # each sweep's own estimate: a timing's, or a check's (not the kept latency a check that agrees pairs with)
    failures: list[str]  # each cycle that did not install: its seed, trial, outcome and reason
    spent_s: list[dict[str, float]]  # each installed cycle's time by what it was spent on (SpentPerCycle)

    def summary(self) -> dict[str, Any]:
        steps = sorted({n for s in self.step_s for n in s})
        spent_on = sorted({n for s in self.spent_s for n in s})
        return {
            "mode": self.mode,
            "installed": self.installed,
            "requested": self.requested,
            "aligned_on_the_fly": self.on_the_fly,
            "cycle_median_s": percentile(self.cycle_s, 50),
            "cycle_p95_s": percentile(self.cycle_s, 95),
            "step_median_s": {n: percentile([s.get(n, 0.0) for s in self.step_s], 50) for n in steps},
            "spent_median_s": {n: percentile([s.get(n, 0.0) for s in self.spent_s], 50) for n in spent_on},
            "p99_abs": {a.label: percentile(np.abs(self.errors[:, i]).tolist(), 99) for i, a in enumerate(AXES)},
            # The bulk beside the tail: p99 of a few dozen cycles is near their largest and moves with one of them.
            "mean": {a.label: float(np.mean(self.errors[:, i])) if len(self.errors) else float("nan") for i, a in enumerate(AXES)},
            "rms": {a.label: float(np.sqrt(np.mean(self.errors[:, i] ** 2))) if len(self.errors) else float("nan")
                    for i, a in enumerate(AXES)},
            # The p99 a normal with these cycles' mean and std would have: the tail from the bulk, not from one cycle.
            "p99_normal": {a.label: float(normal_p99_abs(self.errors[:, i])) if len(self.errors) > 1 else float("nan")
                           for i, a in enumerate(AXES)},
            "latency_ms_median": percentile(self.latency_ms, 50) if self.latency_ms else None,
            "latency_modes": self.latency_modes,
            "latency_estimates": len(self.estimated_ms),
            "failures": self.failures,
        }


def _figures(
    mode: str, runs: list[AccuracyRun], latencies: list[float], on_the_fly: int, spent: list[SpentPerCycle]
) -> ModeFigures:
    installed = [t for r in runs for t in r.installed]
    modes = Counter(str(a["latency"]) for a in (t.align or {} for t in installed) if a.get("latency"))
    errors = np.array([[t.true_error[a.field] for a in AXES] for t in installed if t.true_error], dtype=float)
    return ModeFigures(
        mode=mode,
        installed=len(installed),
        requested=sum(len(r.trials) for r in runs),
        cycle_s=[t.cycle_time_s for t in installed if t.cycle_time_s is not None],
        step_s=[t.step_time_s for t in installed if t.step_time_s],
        errors=errors.reshape(-1, len(AXES)),
        on_the_fly=on_the_fly,
        latency_ms=latencies,
        latency_modes=dict(modes),
        estimated_ms=[float(a["latency_ms"]) if a.get("latency") == "timed" else float(a["latency_check"]["checked_ms"])
                      for a in (t.align or {} for t in installed) if a.get("latency") == "timed" or "latency_check" in a],
        failures=[
            f"seed {r.settings.seed} trial {t.index}: {t.outcome}: {t.reason or 'no reason recorded'}"
            for r in runs for t in r.not_installed
        ],
        spent_s=[ledger.by_trial[t.index] for r, ledger in zip(runs, spent, strict=True) for t in r.installed
                 if t.index in ledger.by_trial],
    )


def run_cycle_time(config: CellConfig, *, cells: int, trials: int, seed: int, progress: bool = True) -> dict[str, Any]:
    """Both modes on ``cells`` twins (seeds ``seed`` ...), ``trials`` cycles each; the figures and the bar."""
    out: dict[str, Any] = {"cells": cells, "trials": trials, "seed": seed}
    twin = config.sim
    true_s = twin.laser.storage_latency_s + twin.robot.path_lag_s - twin.robot.feedback_latency_s
    out["true_latency_ms"] = 1e3 * true_s
    variants = {
        "stop_and_go": with_align_mode(config, "stop_and_go"),
        "on_the_fly": with_align_mode(config, "on_the_fly"),
        UNCOMPENSATED: with_align_mode(config, "on_the_fly", fixed_latency_s=true_s - LATENCY_ERROR_S),
    }
    figures: dict[str, ModeFigures] = {}
    for mode, variant in variants.items():
        runs: list[AccuracyRun] = []
        latencies: list[float] = []
        swept = 0
        ledgers: list[SpentPerCycle] = []
        for s in range(seed, seed + cells):
            settings = RunSettings(trials=trials, seed=s, calibration="oracle", devices="twin", label=f"{mode} seed {s}")
            ledgers.append(SpentPerCycle())
            run = run_accuracy(variant, settings, progress=progress, hooks=ledgers[-1])
            runs.append(run)
            aligns = [t.align or {} for t in run.installed]
            swept += sum(1 for a in aligns if a.get("mode") == "on_the_fly")
            latencies += [float(a["latency_ms"]) for a in aligns if a.get("latency_ms") is not None]
        figures[mode] = _figures(mode, runs, latencies, swept, ledgers)
        out[mode] = figures[mode].summary()
    slow, fast = out["stop_and_go"], out["on_the_fly"]
    ratio = fast["cycle_median_s"] / slow["cycle_median_s"] if slow["cycle_median_s"] else float("nan")
    worse = {a.label: fast["p99_abs"][a.label] - slow["p99_abs"][a.label] for a in AXES}
    out["time_ratio"] = ratio
    out["step_ratio"] = {
        n: fast["step_median_s"][n] / slow["step_median_s"][n]
        for n in ("align", "inspect") if slow["step_median_s"].get(n) and n in fast["step_median_s"]
    }  # fmt: skip
    out["p99_worse"] = worse
    estimated = figures["on_the_fly"].estimated_ms
    out["latency_error_ms_max"] = max((abs(e - out["true_latency_ms"]) for e in estimated), default=None)
    # What the cycles can say: p99 of a few dozen is near their largest, so its change has a wide interval.
    out["p99_worse_interval"] = {
        a.label: p99_difference_interval(figures["stop_and_go"].errors[:, i], figures["on_the_fly"].errors[:, i])
        for i, a in enumerate(AXES)
    }
    out["p99_normal_worse_interval"] = {
        a.label: p99_difference_interval(figures["stop_and_go"].errors[:, i], figures["on_the_fly"].errors[:, i], normal=True)
        for i, a in enumerate(AXES)
    }
    out["sweep_legs"] = sweep_legs_s(config)
    out["bar_met"] = bool(
        ratio <= TIME_RATIO_BAR
        and all(worse[a.label] <= P99_SLACK[a.unit] for a in AXES)
        and fast["aligned_on_the_fly"] == fast["installed"] > 0
    )
    return out


def sweep_legs_s(config: CellConfig) -> dict[str, float]:
    """The robot time of the two sweeps' legs alone (the alignment's, with the one move in along the beam
    that checks a kept latency, and the inspection's), from the twin's motion limits: with a stop at every
    corner as the cell moves now, and flown through every corner at full speed but for a stop where the
    path turns back on itself, the least any blended path along the same corners could take (a real robot
    also slows in a corner's zone)."""
    sweep, robot = config.process.align.sweep, config.sim.robot
    a, settle = robot.acceleration_mm_s2, robot.settle_time_s
    # The alignment's sweep carries the glass, the inspection's does not: each at its own speed.
    speeds = [min(config.process.sweep_speed_mm_s(glass_on_gripper=held), robot.max_speed_mm_s) for held in (True, False)]

    def runs(path_mm: tuple[tuple[float, float], ...], first_mm: float = 0.0) -> list[list[float]]:
        """The legs' lengths, in runs between the corners where the path turns back (the move in comes first)."""
        steps = np.diff(np.asarray(path_mm, dtype=float), axis=0)
        out = [[first_mm]] if first_mm else [[]]
        for k, step in enumerate(steps):
            if k and float(step @ steps[k - 1]) <= -(1.0 - 1e-9) * float(np.linalg.norm(step) * np.linalg.norm(steps[k - 1])):
                out.append([])
            out[-1].append(float(np.linalg.norm(step)))
        return out

    paths = (runs(sweep.path_mm, sweep.approach_mm), runs(config.process.inspect.sweep_path_mm))
    stopping = sum(TrapezoidProfile(L, v, a).duration + settle for path, v in zip(paths, speeds) for run in path for L in run)
    flown = sum(sum(TrapezoidProfile(sum(run), v, a).duration for run in path) + settle for path, v in zip(paths, speeds))
    length = sum(L for path in paths for run in path for L in run)
    return {"length_mm": float(length), "speeds_mm_s": speeds, "stopping_s": stopping, "flown_s": flown}


def format_cycle_time(out: dict[str, Any]) -> str:
    """The two modes side by side: cycle time, per step, p99 per axis, the ratio and the bar."""
    slow, fast = out["stop_and_go"], out["on_the_fly"]
    lines = [
        f"cycle time: stop and go against on the move, {out['cells']} cells (seeds {out['seed']}..{out['seed'] + out['cells'] - 1}) "
        f"x {out['trials']} cycles, the twin's devices, on the cell's clock (simulated robot seconds)",
    ]
    for m in (slow, fast):
        lines.append(
            f"  {m['mode']:12s} installed {m['installed']}/{m['requested']}; cycle median {m['cycle_median_s']:.2f} s, "
            f"p95 {m['cycle_p95_s']:.2f} s; per step (median): "
            + ", ".join(f"{n} {v:.2f}" for n, v in sorted(m["step_median_s"].items(), key=lambda kv: -kv[1]) if v >= 0.005)
        )
    for m in (slow, fast, out[UNCOMPENSATED]):
        lines += [f"  {m['mode']} did not install: {f}" for f in m["failures"]]
    lat = fast["latency_ms_median"]
    modes = ", ".join(f"{k} in {v}" for k, v in sorted(fast["latency_modes"].items())) or "-"
    lines.append(
        f"  on the move: {fast['aligned_on_the_fly']} of {fast['installed']} alignments read on the move; "
        f"laser-to-robot latency {'-' if lat is None else f'{lat:.2f} ms'} (median; {modes})"
    )
    if out.get("latency_error_ms_max") is not None:
        lines.append(
            f"  each of the {fast['latency_estimates']} timings and checks within {out['latency_error_ms_max']:.3f} ms "
            f"of the twin's {out['true_latency_ms']:.2f} ms (bar 1 ms)"
        )
    lines.append(f"  median cycle time ratio on the move / stop and go: {out['time_ratio']:.3f} (bar <= {TIME_RATIO_BAR})")
    steps = ", ".join(f"{n} {r:.3f}" for n, r in out["step_ratio"].items())
    shared = sum(v for n, v in fast["step_median_s"].items() if n not in out["step_ratio"])
    # on the move's cycle is shared + its own reading steps; half of stop and go leaves them this much
    room = TIME_RATIO_BAR * slow["cycle_median_s"] - shared
    lines.append(
        f"  per step (median ratio): {steps}; the other steps take {shared:.2f} s in both modes, so the bar leaves "
        f"align and inspect on the move {room:.2f} s together (now {fast['cycle_median_s'] - shared:.2f} s)"
    )
    legs = out["sweep_legs"]
    rest = fast["cycle_median_s"] - shared - legs["stopping_s"]
    lines.append(
        f"  of which the sweeps' legs ({legs['length_mm']:.0f} mm at {legs['speeds_mm_s'][0]:g} mm/s with the glass and "
        f"{legs['speeds_mm_s'][1]:g} mm/s without) take {legs['stopping_s']:.2f} s "
        f"stopping at every corner, and would take {legs['flown_s']:.2f} s at the least flown through every corner at full "
        f"speed (stopping only where the path turns back): with the rest as now ({rest:.2f} s) align and inspect could not take under {legs['flown_s'] + rest:.2f} s"
    )
    lines += _spent_table(slow, fast)
    bad = out[UNCOMPENSATED]
    lines.append(
        f"  (the twin's latency is {out['true_latency_ms']:.2f} ms; the third run pairs with it {1e3 * LATENCY_ERROR_S:g} ms off, "
        f"cycle median {bad['cycle_median_s']:.2f} s)"
    )
    lines.append(
        "  axis   p99|e| stop and go   p99|e| on the move   difference (95 % bootstrap interval)   allowed   "
        "p99|e| latency 10 ms off"
    )
    for a in AXES:
        lo, hi = out["p99_worse_interval"][a.label]
        lines.append(
            f"  {a.label:4s} {slow['p99_abs'][a.label]:12.4f} {a.unit:3s} {fast['p99_abs'][a.label]:14.4f} {a.unit:3s} "
            f"{out['p99_worse'][a.label]:+11.4f} ({lo:+.4f} .. {hi:+.4f})   <= {P99_SLACK[a.unit]:g}  "
            f"{bad['p99_abs'][a.label]:14.4f} {a.unit}"
        )
    lines.append("  axis   mean e stop and go / on the move   RMS e stop and go / on the move")
    lines += [
        f"  {a.label:4s} {slow['mean'][a.label]:+12.4f} / {fast['mean'][a.label]:+.4f} {a.unit:3s}     "
        f"{slow['rms'][a.label]:12.4f} / {fast['rms'][a.label]:.4f} {a.unit}"
        for a in AXES
    ]
    lines.append("  axis   p99 of a normal fit (mean, std) stop and go / on the move   difference (95 % bootstrap interval)")
    for a in AXES:
        lo, hi = out["p99_normal_worse_interval"][a.label]
        worse = fast["p99_normal"][a.label] - slow["p99_normal"][a.label]
        lines.append(
            f"  {a.label:4s} {slow['p99_normal'][a.label]:12.4f} / {fast['p99_normal'][a.label]:.4f} {a.unit:3s} "
            f"{worse:+24.4f} ({lo:+.4f} .. {hi:+.4f})"
        )
    lines.append(f"  bar: {'met' if out['bar_met'] else 'NOT met'} (on the p99 of the cycles themselves)")
    return "\n".join(lines)


def _spent_table(slow: dict[str, Any], fast: dict[str, Any]) -> list[str]:
    """Where each mode's cycle time goes (median seconds per ledger entry, largest first)."""
    a, b = slow["spent_median_s"], fast["spent_median_s"]
    names = sorted(set(a) | set(b), key=lambda n: -max(a.get(n, 0.0), b.get(n, 0.0)))
    lines = [f"  {'where the time goes (median s)':46s} stop and go   on the move"]
    lines += [f"    {n:44s} {a.get(n, 0.0):11.2f} {b.get(n, 0.0):13.2f}" for n in names if max(a.get(n, 0.0), b.get(n, 0.0)) >= 0.005]
    return lines
