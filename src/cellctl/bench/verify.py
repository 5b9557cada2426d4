"""``cellctl bench verify``: does ``cellctl calibrate verify`` see a moved camera, and stay quiet otherwise?

Per seed (one simulated cell each): camera, hand-eye and laser are calibrated by their
commissioning procedures, then the verification runs on the unchanged cell and again after the
twin's camera was moved on the flange (the true T_H_C changed; the stored calibration not):
by 0.3 mm and 0.05 deg together, by 0.3 mm alone, and by 0.05 deg alone, each in a direction
drawn per seed. The report gives the drift each check measured and whether it raised the alarm
(``calibration.procedure.verify``'s limits), per case and seed, and how many seeds alarmed.
"""

from __future__ import annotations

import asyncio
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
from cellctl.calibration.recording import record
from cellctl.commissioning.registry import ALL_PROCEDURES
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import Pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix
from cellctl.sim.commissioning import TwinCommissioning


@dataclass(frozen=True)
class Change:
    """A move of the camera on the flange: translation (mm) and rotation (deg), directions drawn per seed."""

    name: str
    translation_mm: float
    rotation_deg: float
    should_alarm: bool


CHANGES: tuple[Change, ...] = (
    Change("unchanged", 0.0, 0.0, False),
    Change("0.3 mm + 0.05 deg", 0.3, 0.05, True),
    Change("0.3 mm", 0.3, 0.0, True),
    Change("0.05 deg", 0.0, 0.05, True),
)


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def camera_move(change: Change, rng: np.random.Generator) -> Pose:
    """The change as a pose in the camera frame (T_H_C_new = T_H_C @ move)."""
    return make_pose(axis_angle_to_matrix(np.radians(change.rotation_deg) * _unit(rng)), change.translation_mm * _unit(rng))


@dataclass
class CaseResult:
    seed: int
    change: str
    alarmed: bool
    hand_eye_mm: float
    hand_eye_deg: float
    laser_r_mm: float | None
    laser_l_deg: float | None
    hand_eye_sigma_mm: float


@dataclass
class VerifyBench:
    results: list[CaseResult] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)
    robot_s: float = 0.0

    def cases(self, change: str) -> list[CaseResult]:
        return [r for r in self.results if r.change == change]

    def passed(self) -> bool:
        return not self.refused and all(r.alarmed == _expected(r.change) for r in self.results)

    def as_dict(self) -> dict[str, Any]:
        return {
            "cases": [r.__dict__ for r in self.results],
            "refused": self.refused,
            "robot_time_s": self.robot_s,
            "summary": {c.name: {"alarms": sum(r.alarmed for r in self.cases(c.name)), "seeds": len(self.cases(c.name))} for c in CHANGES},
        }


def _expected(name: str) -> bool:
    return next(c.should_alarm for c in CHANGES if c.name == name)


async def _one_seed(config: CellConfig, seed: int, scratch: Path, bench: VerifyBench) -> None:
    tc = TwinCommissioning(config, seed=seed)
    store = CalibrationStore(scratch / f"store-{seed}")
    rng = np.random.default_rng(1000 + seed)
    try:
        for part in ("camera", "hand_eye", "laser"):
            ds = await tc.collect(part, store.current(), scratch / f"{part}-{seed}")
            outcome = await asyncio.to_thread(ALL_PROCEDURES[part].compute, ds, store.current(), config)
            record(store, outcome, ds, config, datetime.now(timezone.utc))
        original = tc.cell.T_H_C.copy()
        for change in CHANGES:
            tc.cell.T_H_C = original @ camera_move(change, rng)
            try:
                ds = await tc.collect("verify", store.current(), scratch / f"verify-{seed}-{change.name.replace(' ', '_')}")
                o = await asyncio.to_thread(ALL_PROCEDURES["verify"].compute, ds, store.current(), config)
            finally:
                tc.cell.T_H_C = original
            he, la = o.quality["hand_eye"], o.quality.get("laser") or {}
            plan = ds.manifest["plan"]
            bench.robot_s = float(plan["estimated_robot_time_s"])
            bench.results.append(CaseResult(
                seed, change.name, not o.quality["passed"], he["translation_mm"], he["rotation_deg"],
                la.get("r_mm"), la.get("l_deg"), he["translation_sigma_mm"],
            ))  # fmt: skip
    finally:
        await tc.close()


def run_verify_bench(config: CellConfig, seeds: Sequence[int], *, progress: bool = True) -> VerifyBench:
    """Calibrate each seed's twin, then verify it unchanged and with its camera moved."""
    bench = VerifyBench()
    bar = Progress("verify seeds", len(seeds), enabled=progress)
    with tempfile.TemporaryDirectory(prefix="cellctl-bench-verify-") as tmp:
        for s in seeds:
            t0 = time.perf_counter()
            try:
                asyncio.run(_one_seed(config, int(s), Path(tmp), bench))
            except Exception as err:  # noqa: BLE001 - a refused calibration or check is reported per seed
                bench.refused.append(f"seed {s}: {type(err).__name__}: {err}")
            bench.seconds.append(time.perf_counter() - t0)
            bar.advance(f"seed {s}")
    return bench


def format_verify_bench(bench: VerifyBench, config: CellConfig) -> str:
    vc = config.calibration.procedure.verify
    lines = [
        f"calibrate verify on {len(bench.seconds)} simulated cells: the camera moved on the flange by each change; "
        f"limits hand-eye {vc.max_hand_eye_mm:g} mm / {vc.max_hand_eye_deg:g} deg, laser {vc.max_laser_r_mm:g} mm / {vc.max_laser_l_deg:g} deg",
        f"the check's robot time: {bench.robot_s:.0f} s ({vc.views} board views, {vc.laser_stands} x {vc.laser_poses_per_stand} laser poses)",
        "",
        f"{'change':20s} {'alarms':>8s}  {'hand-eye mm: median / max':>26s}  {'deg: median / max':>20s}  {'sigma mm':>9s}  {'laser r mm max':>14s}  {'l deg max':>9s}",
    ]
    for c in CHANGES:
        rows = bench.cases(c.name)
        if not rows:
            continue
        mm = [r.hand_eye_mm for r in rows]
        deg = [r.hand_eye_deg for r in rows]
        lr = [r.laser_r_mm for r in rows if r.laser_r_mm is not None]
        ll = [r.laser_l_deg for r in rows if r.laser_l_deg is not None]
        want = "all" if c.should_alarm else "none"
        lines.append(
            f"{c.name:20s} {sum(r.alarmed for r in rows):>3d} / {len(rows):<2d}  {statistics.median(mm):11.3f} / {max(mm):.3f} mm"
            f"  {statistics.median(deg):9.4f} / {max(deg):.4f}  {statistics.median(r.hand_eye_sigma_mm for r in rows):9.3f}"
            f"  {max(lr, default=float('nan')):14.3f}  {max(ll, default=float('nan')):9.4f}   (want {want})"
        )
    for why in bench.refused:
        lines.append(f"refused: {why}")
    lines.append(f"\nwall time per seed: median {statistics.median(bench.seconds):.0f} s" if bench.seconds else "")
    lines.append("every case as it should be" if bench.passed() else "MISSED: a case alarmed when it should not, or not when it should")
    return "\n".join(lines)
