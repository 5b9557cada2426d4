"""``cellctl bench calibration``: how well commissioning recovers the twin's mountings, over seeds.

Each seed is a different simulated cell (its own robot accuracy field and repeatability draws,
sensor linearity curve, image noise). For each, the commissioning procedures of the chosen parts
run through the ports exactly as a ``cellctl calibrate`` job runs them (the same procedure
coroutines, the simulated operator answering their prompts; collect a dataset, compute from it),
and the result is compared with the twin's truth, which the computation never sees. The
report gives each figure per seed, then its median and worst beside the bar it must meet.

The laser part also reports what its plan costs on a real robot: the sum of the twin's motion
times (trapezoidal profile at the procedure's speeds, settling included) between the poses.
"""

from __future__ import annotations

import asyncio
import itertools
import statistics
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.bench.progress import Progress
from cellctl.calibration.calibration_set import CalibrationStore
from cellctl.calibration.compute import (
    compute_camera,
    compute_hand_eye,
    compute_laser,
    detect_views,
)
from cellctl.calibration.dataset import pose_array
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.recording import record
from cellctl.commissioning.registry import motion_settings
from cellctl.config.schema import CellConfig
from cellctl.sim.commissioning import TwinCommissioning

PARTS = ("laser", "camera", "hand_eye")


@dataclass(frozen=True)
class Figure:
    """One compared figure: its key in the results, unit, and the bar its size must stay under."""

    key: str
    part: str
    label: str
    unit: str
    bar: float | None


# Issue 5's bars ("it recovers the configured truth"); None: reported, no bar.
FIGURES: tuple[Figure, ...] = (
    Figure("laser_r_mm", "laser", "laser r error", "mm", 0.3),
    Figure("laser_l_deg", "laser", "laser l error", "deg", 0.02),
    Figure("laser_l_sigma_deg", "laser", "laser l reported 1-sigma", "deg", None),
    Figure("laser_robot_min", "laser", "laser plan robot time", "min", None),
    Figure("camera_fx_pct", "camera", "camera fx error", "%", 0.2),
    Figure("camera_fy_pct", "camera", "camera fy error", "%", 0.2),
    Figure("camera_pp_px", "camera", "principal point error", "px", 2.0),
    Figure("camera_rms_px", "camera", "reprojection RMS", "px", 0.2),
    Figure("hand_eye_mm", "hand_eye", "hand-eye translation error", "mm", 0.5),
    Figure("hand_eye_deg", "hand_eye", "hand-eye rotation error", "deg", 0.05),
)


@dataclass
class SeedResult:
    """One seed's figures (absolute values) and any part the procedure refused."""

    seed: int
    figures: dict[str, float] = field(default_factory=dict)
    refused: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0


@dataclass(frozen=True)
class CalibrationBench:
    parts: tuple[str, ...]
    results: tuple[SeedResult, ...]

    def figures(self) -> tuple[Figure, ...]:
        return tuple(f for f in FIGURES if f.part in self.parts)

    def values(self, key: str) -> list[float]:
        return [r.figures[key] for r in self.results if key in r.figures]

    def bars_met(self) -> bool:
        if any(r.refused for r in self.results):
            return False
        return all(f.bar is None or all(v <= f.bar for v in self.values(f.key)) for f in self.figures())

    def as_dict(self) -> dict[str, Any]:
        summary = {}
        for f in self.figures():
            vals = self.values(f.key)
            summary[f.key] = {
                "unit": f.unit,
                "bar": f.bar,
                "median": statistics.median(vals) if vals else None,
                "max": max(vals) if vals else None,
                "over_bar": sum(1 for v in vals if f.bar is not None and v > f.bar),
            }
        return {
            "parts": list(self.parts),
            "seeds": [{"seed": r.seed, "figures": r.figures, "refused": r.refused, "seconds": r.seconds} for r in self.results],
            "summary": summary,
        }


def _plan_robot_minutes(twin: TwinCommissioning, poses: Sequence[np.ndarray], config: CellConfig) -> float:
    motion = motion_settings(config)
    model = twin.cell.robot_model
    total = sum(
        model.motion_time(a, b, motion.speed_mm_s, motion.speed_deg_s) for a, b in itertools.pairwise(poses)
    )
    return total / 60.0


async def _one_seed(config: CellConfig, seed: int, parts: tuple[str, ...], scratch: Path) -> SeedResult:
    out = SeedResult(seed)
    t0 = time.perf_counter()
    twin = TwinCommissioning(config, seed=seed)
    try:
        if "laser" in parts:
            try:
                ds = await twin.collect("laser", None, scratch / f"laser-{seed}")
                o = compute_laser(ds, config)
                truth = o.quality["twin_truth"]
                out.figures["laser_r_mm"] = truth["r_error_mm"]
                out.figures["laser_l_deg"] = truth["l_error_deg"]
                out.figures["laser_l_sigma_deg"] = float(max(o.quality["l_sigma_deg"]))
                poses = [pose_array(r["T_B_H"], "reading.T_B_H") for r in ds.manifest["readings"]]
                out.figures["laser_robot_min"] = _plan_robot_minutes(twin, poses, config)
            except CalibrationRefused as err:
                out.refused["laser"] = str(err)
        if "camera" in parts or "hand_eye" in parts:
            await _board_parts(twin, config, seed, parts, scratch, out)
    finally:
        await twin.close()
    out.seconds = time.perf_counter() - t0
    return out


async def _board_parts(twin: TwinCommissioning, config: CellConfig, seed: int, parts: tuple[str, ...], scratch: Path, out: SeedResult) -> None:
    ds = await twin.collect("camera", None, scratch / f"board-{seed}")
    dets = detect_views(ds, config.calibration.procedure.camera.refine)
    try:
        cam = compute_camera(ds, config, dets)
    except CalibrationRefused as err:
        out.refused["camera"] = str(err)
        return
    t = cam.quality["twin_truth"]
    if "camera" in parts:
        out.figures["camera_fx_pct"] = abs(t["fx_error_pct"])
        out.figures["camera_fy_pct"] = abs(t["fy_error_pct"])
        out.figures["camera_pp_px"] = float(np.hypot(t["cx_error_px"], t["cy_error_px"]))
        out.figures["camera_rms_px"] = float(cam.quality["rms_px"])
    if "hand_eye" in parts:
        store = CalibrationStore(scratch / f"store-{seed}")
        record(store, cam, ds, config, datetime.now(timezone.utc))
        try:
            he = compute_hand_eye(ds, store.current(), config, dets)
        except CalibrationRefused as err:
            out.refused["hand_eye"] = str(err)
            return
        chosen = he.quality["twin_truth"][he.quality["chosen"]]
        out.figures["hand_eye_mm"] = chosen["translation_error_mm"]
        out.figures["hand_eye_deg"] = chosen["rotation_error_deg"]


def run_calibration_bench(
    config: CellConfig, seeds: Sequence[int], parts: Sequence[str] = ("laser",), *, progress: bool = True
) -> CalibrationBench:
    """Run the chosen parts' procedures on one twin per seed and compare with the truth."""
    chosen = tuple(p for p in PARTS if p in parts)
    unknown = sorted(set(parts) - set(PARTS))
    if unknown or not chosen:
        raise ValueError(f"parts must be some of {', '.join(PARTS)}; got {', '.join(parts) or 'none'}")
    bar = Progress("calibration seeds", len(seeds), enabled=progress)
    results = []
    with tempfile.TemporaryDirectory(prefix="cellctl-bench-calibration-") as tmp:
        for s in seeds:
            res = asyncio.run(_one_seed(config, int(s), chosen, Path(tmp)))
            results.append(res)
            bar.advance(f"seed {s}: " + ("refused " + ", ".join(res.refused) if res.refused else "ok"))
    return CalibrationBench(chosen, tuple(results))


def format_calibration_bench(bench: CalibrationBench) -> str:
    figs = bench.figures()
    lines = [f"Calibration against the twin's truth, {len(bench.results)} seeds, parts: {', '.join(bench.parts)}", ""]
    head = "seed  " + "  ".join(f"{f.key:>18s}" for f in figs)
    lines.append(head)
    for r in bench.results:
        cells = "  ".join(f"{r.figures[f.key]:18.4f}" if f.key in r.figures else f"{'-':>18s}" for f in figs)
        lines.append(f"{r.seed:<5d} {cells}")
        for part, why in r.refused.items():
            lines.append(f"      {part} refused: {why}")
    lines += ["", f"{'figure':30s} {'unit':>4s} {'median':>9s} {'worst':>9s} {'bar':>7s}  seeds over the bar"]
    for f in figs:
        vals = bench.values(f.key)
        if not vals:
            continue
        over = sum(1 for v in vals if f.bar is not None and v > f.bar)
        bar = f"{f.bar:g}" if f.bar is not None else "-"
        lines.append(
            f"{f.label:30s} {f.unit:>4s} {statistics.median(vals):9.4f} {max(vals):9.4f} {bar:>7s}  "
            + (f"{over} of {len(vals)}" if f.bar is not None else "")
        )
    secs = [r.seconds for r in bench.results]
    lines.append(f"\nwall time per seed: median {statistics.median(secs):.1f} s")
    return "\n".join(lines)
