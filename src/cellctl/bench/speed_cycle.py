"""``cellctl bench speed``, the cycle's compute overhead.

Cycles through the orchestrator of the composition root with ``sim.time_scale = 0`` and the
devices wrapped in timing proxies: overhead = the record's cycle time minus the time inside device
calls (moves, reads, grabs; the grab is where the twin renders). What stays is the cell's own
work; the cycles' frames are timed again alone to split it into detection, annotation and the rest.
"""

from __future__ import annotations

import asyncio
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.bench.accuracy import bring_to_execute, prepare_calibration
from cellctl.bench.progress import Progress
from cellctl.bench.sources import run_config
from cellctl.bench.stats import percentile
from cellctl.config import CellConfig

OVERHEAD_TARGET_S = 0.150  # issue 10: the cycle's compute overhead, median


class _DeviceTimer:
    """Wraps a device port and adds the wall time of each call a cycle makes to a shared account."""

    TIMED = ("move", "read", "grab", "read_pose", "state", "stop", "set_gripper")

    def __init__(self, inner: Any, account: dict[str, float], frames: list[np.ndarray] | None = None) -> None:
        self._inner = inner
        self._account = account
        self._frames = frames

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._inner, name)
        if name not in self.TIMED:
            return attr

        async def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                out = await attr(*args, **kwargs)
            finally:
                self._account[name] = self._account.get(name, 0.0) + time.perf_counter() - t0
            if name == "grab" and self._frames is not None:
                self._frames.append(out.image)
            return out

        return timed


async def _overhead_async(config: CellConfig, cycles: int, workdir: Path, progress: Progress) -> dict[str, Any]:
    from cellctl.service import build_service
    from cellctl.store import CycleRequest, CycleState

    service = await build_service(config, workdir=workdir)
    await service.start()
    rows: list[dict[str, Any]] = []
    frames_per_cycle: list[list[np.ndarray]] = []
    try:
        orch = service.orchestrator
        await prepare_calibration(service, 3600.0)
        await bring_to_execute(orch)
        original = orch.devices
        recipe = next(iter(config.process.recipe_names().values()))
        for k in range(cycles + 1):  # the first is a warm-up (first-call costs), not counted
            account: dict[str, float] = {}
            frames: list[np.ndarray] = []
            orch.devices = replace(
                original, laser=_DeviceTimer(original.laser, account), camera=_DeviceTimer(original.camera, account, frames),
                robot=_DeviceTimer(original.robot, account),
            )  # fmt: skip
            try:
                if orch.machine.state.name != "EXECUTE":
                    await bring_to_execute(orch)
                sub = await orch.submit_cycle(
                    CycleRequest(recipe, f"speed-{k}", source="bench"), scope="bench-speed", key=f"speed-{k}", actor="bench"
                )
                rec = await orch.wait_cycle(sub.cycle.id, 300.0)
            finally:
                orch.devices = original
            if k == 0:
                continue
            ok = rec.state is CycleState.DONE
            res = rec.result or {}
            cycle_s = float(res.get("wall_time_s") or float("nan"))  # the host's seconds: what the overhead is taken from
            robot_s = float(res.get("cycle_time_s") or float("nan"))  # the cell's clock: the robot time of the cycle
            device_s = sum(account.values())
            rows.append({"ok": ok, "cycle_s": cycle_s, "robot_s": robot_s, "device_s": device_s, "by_call_s": dict(account),
                         "shots": len(frames)})  # fmt: skip
            frames_per_cycle.append(frames)
            progress.advance("ok" if ok else f"failed: {rec.error}")
    finally:
        await service.stop()
    return _overhead_figures(config, rows, frames_per_cycle)


def _overhead_figures(config: CellConfig, rows: list[dict[str, Any]], frames_per_cycle: list[list[np.ndarray]]) -> dict[str, Any]:
    """The overhead per cycle, and its split by timing detection and annotation again on the cycle's frames."""
    from cellctl.vision import Lens, annotate, detect_corner

    lens = Lens.from_intrinsics(config.sim.camera.intrinsics)
    ok_rows = [(r, f) for r, f in zip(rows, frames_per_cycle) if r["ok"]]
    detect_c, annotate_c = [], []
    for _, frames in ok_rows:
        d = a = 0.0
        for i, img in enumerate(frames):
            t0 = time.perf_counter()
            m = detect_corner(img, lens, config.vision)
            t1 = time.perf_counter()
            if i == len(frames) - 1:  # a cycle annotates its final shot only (and refused ones)
                annotate(img, m, lens)
            t2 = time.perf_counter()
            d += t1 - t0
            a += t2 - t1
        detect_c.append(d)
        annotate_c.append(a)
    over = [r["cycle_s"] - r["device_s"] for r, _ in ok_rows]
    med = lambda v: percentile(v, 50)  # noqa: E731
    calls: dict[str, list[float]] = {}
    for r, _ in ok_rows:
        for name, s in r["by_call_s"].items():
            calls.setdefault(name, []).append(s)
    rest = [o - d - a for o, d, a in zip(over, detect_c, annotate_c)]
    return {
        "cycles": len(rows),
        "failed": sum(1 for r in rows if not r["ok"]),
        "time_scale": config.sim.time_scale,
        "cycle_median_s": med([r["cycle_s"] for r, _ in ok_rows]),
        "robot_cycle_median_s": med([r["robot_s"] for r, _ in ok_rows]),
        "robot_cycle_p95_s": percentile([r["robot_s"] for r, _ in ok_rows], 95),
        "device_median_s": med([r["device_s"] for r, _ in ok_rows]),
        "device_calls_median_s": {k: med(v) for k, v in sorted(calls.items())},
        "overhead_median_s": med(over) if over else None,
        "overhead_p90_s": percentile(over, 90),
        "shots_median": med([float(r["shots"]) for r, _ in ok_rows]),
        "split_median_s": {"corner_detection": med(detect_c), "annotated_images": med(annotate_c), "rest": med(rest)},
        "per_shot_median_s": {
            "corner_detection": med([d / max(len(f), 1) for d, (_, f) in zip(detect_c, ok_rows)]),
            "annotated_image": med(annotate_c),  # one per cycle: the final shot
        },
        "target_s": OVERHEAD_TARGET_S,
    }


def measure_overhead(base: CellConfig, cycles: int, seed: int, progress: Progress) -> dict[str, Any]:
    """The cycle's compute overhead with simulated time switched off (see the module docstring)."""
    with tempfile.TemporaryDirectory(prefix="cellctl-speed-") as tmp:
        config = run_config(base, workdir=Path(tmp), seed=seed, calibration="oracle", time_scale=0.0)
        return asyncio.run(_overhead_async(config, cycles, Path(tmp), progress))
