"""``cellctl bench speed``: where the cell's time goes, as medians and ratios.

Five measurements, one module each: vision (:mod:`~cellctl.bench.speed_vision`), alignment
(:mod:`~cellctl.bench.speed_align`), the cycle's compute overhead (:mod:`~cellctl.bench.speed_cycle`),
GET /status under load (:mod:`~cellctl.bench.speed_status`) and the drivers' own benchmarks
(:mod:`~cellctl.bench.speed_drivers`). This module runs them in that order and formats the report.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from cellctl.bench.progress import Progress
from cellctl.bench.sources import BenchSettingsError
from cellctl.bench.speed_align import measure_alignment
from cellctl.bench.speed_cycle import OVERHEAD_TARGET_S, measure_overhead
from cellctl.bench.speed_drivers import run_driver_bench
from cellctl.bench.speed_status import measure_status
from cellctl.bench.speed_vision import measure_vision
from cellctl.config import CellConfig


@dataclass(frozen=True)
class SpeedSettings:
    """How much of each measurement to run (each is bounded)."""

    frames: int = 30
    alignments: int = 200
    cycles: int = 15
    clients: int = 16
    requests: int = 2000
    max_seconds: float = 20.0
    drivers: bool = True
    abb_seconds: float = 5.0
    seed: int = 1

    def __post_init__(self) -> None:
        for name in ("frames", "alignments", "cycles", "clients", "requests"):
            if getattr(self, name) < 1:
                raise BenchSettingsError(f"--{name} must be at least 1, got {getattr(self, name)}")
        if not (0 < self.max_seconds <= 600):
            raise BenchSettingsError(f"--seconds must lie in (0, 600], got {self.max_seconds}")
        if not (0 < self.abb_seconds <= 600):
            raise BenchSettingsError(f"--abb-seconds must lie in (0, 600], got {self.abb_seconds}")


@dataclass
class SpeedReport:
    """Every figure of the speed benchmark, one dict per measurement."""

    settings: SpeedSettings
    vision: dict[str, Any] = field(default_factory=dict)
    alignment: dict[str, Any] = field(default_factory=dict)
    overhead: dict[str, Any] = field(default_factory=dict)
    status: dict[str, Any] = field(default_factory=dict)
    drivers: list[dict[str, Any]] = field(default_factory=list)

    def targets_met(self) -> bool:
        med = self.overhead.get("overhead_median_s")
        return med is not None and med <= OVERHEAD_TARGET_S

    def as_dict(self) -> dict[str, Any]:
        return {
            "benchmark": "speed",
            "settings": asdict(self.settings),
            "vision": self.vision,
            "alignment": self.alignment,
            "cycle_overhead": self.overhead,
            "status_latency": self.status,
            "drivers": self.drivers,
            "overhead_target_s": OVERHEAD_TARGET_S,
            "targets_met": self.targets_met(),
        }


def run_speed(config: CellConfig, settings: SpeedSettings, *, progress: bool = True) -> SpeedReport:
    """Run every measurement and return the figures."""
    if config.mode != "sim":
        raise BenchSettingsError("bench speed runs on the simulated cell (mode = \"sim\")")
    report = SpeedReport(settings)
    bar = Progress("vision", settings.frames, enabled=progress)
    bar.message(f"vision: {settings.frames} corner detections (one core) ...")
    report.vision = measure_vision(config, settings.frames, settings.seed, bar)
    bar = Progress("alignment", settings.alignments, enabled=progress)
    report.alignment = measure_alignment(config, settings.alignments, settings.seed, bar)
    bar = Progress("cycle overhead", settings.cycles, enabled=progress)
    bar.message(f"cycle overhead: {settings.cycles} cycles at sim.time_scale 0 (after a warm-up cycle) ...")
    report.overhead = measure_overhead(config, settings.cycles, settings.seed, bar)
    bar = Progress("GET /status", 3, enabled=progress)
    bar.message("GET /status under load: starting the service on loopback ...")
    report.status = measure_status(config, settings, bar)
    if settings.drivers:
        bar = Progress("drivers", 2, enabled=progress)
        bar.message("driver benchmarks (subprocesses) ...")
        report.drivers.append(run_driver_bench("keyence_lkg.bench", []))
        bar.advance("keyence_lkg")
        report.drivers.append(run_driver_bench("abb_robot.bench", ["--seconds", f"{settings.abb_seconds:g}"]))
        bar.advance("abb_robot")
    return report


def _ms(v: float | None) -> str:
    return "-" if v is None or v != v else f"{v * 1e3:7.1f} ms"


def format_speed(r: SpeedReport) -> str:
    """The speed report as text."""
    v, a, o = r.vision, r.alignment, r.overhead
    lines = [
        "speed of the cell's compute (medians; this machine, with whatever else runs on it)",
        "",
        f"vision: window-corner detector on {v['size_px'][0]} x {v['size_px'][1]} shooting views, one core, "
        f"{v['frames']} runs over {v['distinct_frames']} rendered frames ({v['refused']} refused)",
        f"  corner detection per frame   {_ms(v['detect_median_s'])}  (p90 {_ms(v['detect_p90_s']).strip()})",
        f"  cv2.Canny alone, same frames {_ms(v['canny_median_s'])}",
        f"  ratio detection / Canny      {v['ratio_to_canny']:7.1f} x",
        "",
        f"alignment: compute_alignment on {a['spots']} laser spots measured in the twin, {a['calls']} calls",
        f"  compute_alignment            {a['align_median_s'] * 1e6:7.0f} us  (p90 {a['align_p90_s'] * 1e6:.0f} us)",
        f"  bare plane fit (SVD)         {a['svd_median_s'] * 1e6:7.0f} us",
        f"  ratio                        {a['ratio_to_svd']:7.1f} x",
        "",
        f"cycle compute overhead: {o['cycles']} cycles through the orchestrator, sim.time_scale {o['time_scale']:g} "
        f"({o['failed']} failed), {o['shots_median']:.0f} shots per cycle (median)",
        "  method: cycle time from the record minus the time inside device calls (timing proxies around the",
        "  robot, laser and camera ports; the camera's grab is where the twin renders the frame); detection and",
        "  annotation split out by timing them again on the cycle's own frames",
        f"  cycle time on the cell's clock (the robot time a real cell would take): median {o['robot_cycle_median_s']:.2f} s, "
        f"p95 {o['robot_cycle_p95_s']:.2f} s",
        f"  host time at time scale 0    {_ms(o['cycle_median_s'])}",
        f"  inside device calls          {_ms(o['device_median_s'])}  "
        + ", ".join(f"{k} {_ms(s).strip()}" for k, s in o["device_calls_median_s"].items()),
        f"  compute overhead             {_ms(o['overhead_median_s'])}  (p90 {_ms(o['overhead_p90_s']).strip()})",
        f"    of which corner detection  {_ms(o['split_median_s']['corner_detection'])}  "
        f"({_ms(o['per_shot_median_s']['corner_detection']).strip()} per shot)",
        f"    of which annotated images  {_ms(o['split_median_s']['annotated_images'])}  "
        "(the final shot only)",
        f"    the rest (alignment, store, state machine, event loop) {_ms(o['split_median_s']['rest']).strip()}",
        f"  target: median overhead <= {OVERHEAD_TARGET_S * 1e3:.0f} ms: {'met' if r.targets_met() else 'NOT met'}",
        "",
        f"GET /status under load: {r.status.get('server', '')}",
    ]
    for phase, label in (("single", "idle cell, one client"), ("idle", "idle cell"), ("busy", "cell running cycles")):
        s = r.status.get(phase, {})
        if "skipped" in s:
            lines.append(f"  {label}: skipped ({s['skipped']})")
            continue
        extra = f", {s['cycles_finished_meanwhile']} cycles finished meanwhile" if "cycles_finished_meanwhile" in s else ""
        lines.append(
            f"  {label:21s} {s['clients']} client(s), {s['requests']} requests in {s['seconds']:.1f} s "
            f"({s['per_s']:.0f}/s, {s['errors']} errors{extra}): p50 {s['p50_ms']:.1f} ms, p99 {s['p99_ms']:.1f} ms, "
            f"max {s['max_ms']:.1f} ms"
        )
    for d in r.drivers:
        lines += ["", f"driver: {d['command']}"]
        if "skipped" in d:
            lines.append(f"  skipped: {d['skipped']}")
            continue
        lines += ["  " + ln for ln in d["output"].splitlines()]
        if d["exit_code"]:
            lines.append(f"  (exit code {d['exit_code']}) " + " | ".join(d["stderr_tail"]))
    return "\n".join(lines)
