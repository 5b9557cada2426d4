"""``cellctl bench speed``: where the cell's time goes, as medians and ratios.

1. Vision: the window-corner detector (paper 4.2) on 2048 x 2048 shooting views rendered by the
   twin (the scenes of :mod:`cellctl.bench.vision`), one core, and its ratio to ``cv2.Canny``
   alone on the same frames.
2. Alignment: ``compute_alignment`` (paper section 3) on laser spots measured in the twin, and its
   ratio to the bare plane fit (an SVD of the centred points).
3. The cycle's compute overhead: cycles through the orchestrator of the composition root with
   ``sim.time_scale = 0`` (simulated motion and latencies take no time) and the devices wrapped
   in timing proxies. Overhead = the cycle time the record carries minus the time spent inside
   device calls (robot moves and reads, laser reads, camera grabs: the grab is where the twin
   renders the image, the camera's exposure and transfer on a real cell). What stays is the
   cell's own work: alignment math, corner detection, the annotated images, the store's writes,
   the state machine and the event loop. The frames of the run are timed again alone to split
   the overhead into detection, annotation and the rest.
4. GET /status latency under load: ``cellctl serve``'s real service (uvicorn on loopback, in its
   own process) and N concurrent httpx clients, bounded in count and time; once with the cell
   idle, once while it runs cycles.
5. Driver figures: ``python -m keyence_lkg.bench`` and ``python -m abb_robot.bench`` as
   subprocesses, their output included as printed.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import json
import multiprocessing as mp
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from cellctl.bench.accuracy import bring_to_execute, prepare_calibration
from cellctl.bench.progress import Progress
from cellctl.bench.sources import BenchSettingsError, run_config
from cellctl.bench.stats import percentile
from cellctl.config import CellConfig, parse_config

OVERHEAD_TARGET_S = 0.150  # issue 10: the cycle's compute overhead, median
DRIVER_TIMEOUT_S = 600.0


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
    """Every figure of the speed benchmark; ``sections`` keeps the order of the report."""

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


def _median_s(fn: Callable[[], object], runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


# -- 1. vision ------------------------------------------------------------------------------------


def measure_vision(config: CellConfig, frames: int, seed: int, progress: Progress | None = None) -> dict[str, Any]:
    """Median corner detection per frame over distinct shooting views, and cv2.Canny on the same frames."""
    from cellctl.bench.vision import shooting_scene
    from cellctl.sim.camera import CameraRenderer
    from cellctl.vision import Lens, detect_corner

    sim = config.sim
    renderer = CameraRenderer(sim.camera.intrinsics, sim.camera.render)
    lens = Lens.from_intrinsics(sim.camera.intrinsics)
    rng = np.random.default_rng(seed)
    distinct = min(frames, 8)
    images = []
    for _ in range(distinct):
        world, pose = shooting_scene(renderer, sim, rng)
        images.append(renderer.render(pose, world, rng=rng).image)
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        detect_corner(images[0], lens, config.vision)  # warm-up
        detect_t, canny_t, refused = [], [], 0
        c = config.vision.coarse
        for k in range(frames):
            img = images[k % distinct]
            t0 = time.perf_counter()
            m = detect_corner(img, lens, config.vision)
            detect_t.append(time.perf_counter() - t0)
            refused += not m.ok
            t0 = time.perf_counter()
            cv2.Canny(img, c.canny_low, c.canny_high, L2gradient=c.canny_l2_gradient)
            canny_t.append(time.perf_counter() - t0)
            if progress is not None:
                progress.advance()
    finally:
        cv2.setNumThreads(threads)
    d, cn = statistics.median(detect_t), statistics.median(canny_t)
    return {
        "frames": frames,
        "distinct_frames": distinct,
        "size_px": list(images[0].shape[::-1]),
        "detect_median_s": d,
        "detect_p90_s": percentile(detect_t, 90),
        "canny_median_s": cn,
        "ratio_to_canny": d / cn,
        "refused": refused,
        "threads": 1,
    }


# -- 2. alignment ---------------------------------------------------------------------------------


def measure_alignment(config: CellConfig, calls: int, seed: int, progress: Progress | None = None) -> dict[str, Any]:
    """Median ``compute_alignment`` on spots measured in the twin at several car-body postures."""
    from cellctl.align import compute_alignment, plan_spot_poses
    from cellctl.ports import LaserStatus
    from cellctl.sim.alignment_run import shooting_orientation
    from cellctl.sim.cell import SimCell
    from cellctl.sim.world import nominal_world

    cell = SimCell(config.sim, seed=seed)
    laser, align = config.sim.laser, config.process.align
    T_H_C = config.sim.camera.hand_eye.T_H_C()
    T0 = nominal_world(config.sim.world).T_B_T
    planned = plan_spot_poses(T0, align.spots_mm, shooting_orientation(config), laser.r, laser.l, align.laser_standoff_mm)
    inputs = []
    for _ in range(10):
        cell.new_car_body()
        poses, dist = [], []
        for X in planned:
            cell.execute(X)
            status, d = cell.laser_reading()
            if status is LaserStatus.OK and d is not None:
                poses.append(cell.belief_flange_pose())
                dist.append(d)
        if len(dist) >= 3:
            inputs.append((np.stack(poses), np.array(dist)))
    if not inputs:
        raise BenchSettingsError("no car-body posture gave three laser spots; check process.align.spots_mm")
    kw = dict(
        range_mm=(laser.range_min_mm, laser.range_max_mm), inlier_threshold_mm=align.inlier_threshold_mm,
        max_rms_mm=align.max_rms_mm, min_collinearity=align.min_collinearity, T_B_H_current=planned[-1],
    )  # fmt: skip
    wd = config.process.working_distance_mm
    compute_alignment(inputs[0][0], inputs[0][1], laser.r, laser.l, T_H_C, wd, **kw)  # warm-up
    align_t, svd_t = [], []
    for k in range(calls):
        poses, dist = inputs[k % len(inputs)]
        t0 = time.perf_counter()
        res = compute_alignment(poses, dist, laser.r, laser.l, T_H_C, wd, **kw)
        align_t.append(time.perf_counter() - t0)
        pts = res.points_B
        t0 = time.perf_counter()
        np.linalg.svd(pts - pts.mean(axis=0))
        svd_t.append(time.perf_counter() - t0)
        if progress is not None:
            progress.advance()
    a, s = statistics.median(align_t), statistics.median(svd_t)
    return {
        "calls": calls,
        "spots": len(planned),
        "align_median_s": a,
        "align_p90_s": percentile(align_t, 90),
        "svd_median_s": s,
        "ratio_to_svd": a / s,
    }


# -- 3. the cycle's compute overhead ------------------------------------------------------------


class _DeviceTimer:
    """Wraps a device port and adds the wall time of each call a cycle makes to a shared account."""

    TIMED = ("move", "read", "grab", "read_pose", "state", "stop")

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
    from cellctl.cell.cycle import CellDevices
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
            orch.devices = CellDevices(
                _DeviceTimer(original.laser, account), _DeviceTimer(original.camera, account, frames),
                _DeviceTimer(original.robot, account),
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
            cycle_s = float((rec.result or {}).get("cycle_time_s") or float("nan"))
            device_s = sum(account.values())
            rows.append({"ok": ok, "cycle_s": cycle_s, "device_s": device_s, "by_call_s": dict(account), "shots": len(frames)})
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


# -- 4. GET /status under load ---------------------------------------------------------------------


def _free_port(host: str) -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _serve_child(config_json: str, workdir: str, log_path: str) -> None:
    """Child process: the real service (``cellctl serve``'s path) on loopback, its log to a file."""
    log = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(log, 1)
    os.dup2(log, 2)
    from cellctl.service import build_service

    config = parse_config(json.loads(config_json), "bench speed server")

    async def run() -> None:
        service = await build_service(config, workdir=Path(workdir))
        await service.serve()

    asyncio.run(run())


async def _load(url: str, clients: int, requests: int, max_seconds: float, headers: dict[str, str]) -> dict[str, Any]:
    import httpx

    latencies: list[float] = []
    errors: list[str] = []
    issued = 0
    deadline = time.monotonic() + max_seconds
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)

    async with httpx.AsyncClient(base_url=url, limits=limits, timeout=10.0, headers=headers) as client:

        async def worker() -> None:
            nonlocal issued
            while issued < requests and time.monotonic() < deadline:
                issued += 1
                t0 = time.perf_counter()
                try:
                    r = await client.get("/status")
                    if r.status_code != 200:
                        errors.append(f"HTTP {r.status_code}")
                        continue
                except httpx.HTTPError as err:
                    errors.append(type(err).__name__)
                    continue
                latencies.append(time.perf_counter() - t0)

        t0 = time.monotonic()
        await asyncio.gather(*(worker() for _ in range(clients)))
        elapsed = time.monotonic() - t0
    return {
        "requests": len(latencies),
        "errors": len(errors),
        "error_kinds": sorted(set(errors))[:5],
        "clients": clients,
        "seconds": elapsed,
        "per_s": len(latencies) / elapsed if elapsed > 0 else 0.0,
        "p50_ms": percentile(latencies, 50) * 1e3,
        "p99_ms": percentile(latencies, 99) * 1e3,
        "max_ms": max(latencies) * 1e3 if latencies else float("nan"),
    }


async def _status_phases(
    url: str, settings: SpeedSettings, token: str | None, recipe: str, progress: Progress
) -> dict[str, Any]:
    import httpx

    auth = {"Authorization": f"Bearer {token}"} if token else {}
    out: dict[str, Any] = {}
    async with httpx.AsyncClient(base_url=url, timeout=30.0, headers=auth) as ctl:
        deadline = time.monotonic() + 60.0
        while True:
            try:
                if (await ctl.get("/status")).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("the service did not answer GET /status within 60 s (see its log)")
            await asyncio.sleep(0.2)
        progress.message("  /status, idle cell, one client ...")
        out["single"] = await _load(url, 1, max(settings.requests // 4, 1), settings.max_seconds, auth)
        progress.advance()
        progress.message(f"  /status, idle cell, {settings.clients} clients ...")
        out["idle"] = await _load(url, settings.clients, settings.requests, settings.max_seconds, auth)
        progress.advance()
        if not token:
            out["busy"] = {"skipped": "no API token with a literal value in the configuration to start cycles"}
            progress.advance()
            return out
        for cmd in ("clear", "reset", "start"):
            await ctl.post(f"/commands/{cmd}")
            for _ in range(200):
                state = (await ctl.get("/status")).json()["state"]
                if not state.endswith("ING"):
                    break
                await asyncio.sleep(0.02)
        if state != "EXECUTE":
            out["busy"] = {"skipped": f"the cell did not reach EXECUTE (it is {state})"}
            progress.advance()
            return out
        stop = asyncio.Event()
        done_cycles = 0

        async def cycles() -> None:
            nonlocal done_cycles
            k = 0
            while not stop.is_set():
                k += 1
                r = await ctl.post(
                    "/cycle", params={"wait": "true", "timeout_s": 120}, json={"recipe": recipe, "part_id": f"load-{k}"},
                    headers={"Idempotency-Key": f"speed-load-{os.getpid()}-{k}"}, timeout=150.0,
                )  # fmt: skip
                if r.status_code >= 400:
                    return
                done_cycles += 1

        runner = asyncio.create_task(cycles())
        await asyncio.sleep(1.0)  # the first cycle is under way
        progress.message("  /status, cell running cycles ...")
        busy = await _load(url, settings.clients, settings.requests, settings.max_seconds, auth)
        stop.set()
        with contextlib.suppress(Exception):
            await asyncio.wait_for(runner, 150.0)
        busy["cycles_finished_meanwhile"] = done_cycles
        out["busy"] = busy
        progress.advance()
    return out


def measure_status(base: CellConfig, settings: SpeedSettings, progress: Progress) -> dict[str, Any]:
    """GET /status latency of the real service on loopback (its own process), idle and while cycling."""
    with tempfile.TemporaryDirectory(prefix="cellctl-speed-serve-") as tmp:
        wd = Path(tmp)
        config = run_config(base, workdir=wd, seed=settings.seed, calibration="oracle")
        data = config.model_dump(mode="json")
        port = _free_port(config.api.host)
        data["api"]["port"] = port
        token = next((t.token for t in config.api.tokens if t.token), None)
        log_path = str(wd / "serve.log")
        child = mp.get_context("spawn").Process(target=_serve_child, args=(json.dumps(data), tmp, log_path), daemon=True)
        child.start()
        try:
            recipe = next(iter(config.process.recipe_names().values()))
            result = asyncio.run(_status_phases(f"http://{config.api.host}:{port}", settings, token, recipe, progress))
        finally:
            child.terminate()
            child.join(15.0)
            if child.is_alive():
                child.kill()
                child.join(5.0)
        result["server"] = f"uvicorn on {config.api.host} (own process, the service's access log on)"
        return result


# -- 5. driver figures ---------------------------------------------------------------------------------


def run_driver_bench(module: str, args: list[str]) -> dict[str, Any]:
    """``python -m module args`` as a subprocess; its output as printed (or why it could not run)."""
    if importlib.util.find_spec(module.split(".")[0]) is None or importlib.util.find_spec(module) is None:
        return {"command": f"python -m {module}", "skipped": f"{module} is not installed"}
    cmd = [sys.executable, "-m", module, *args]
    t0 = time.monotonic()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=DRIVER_TIMEOUT_S, check=False)
    except subprocess.TimeoutExpired:
        return {"command": " ".join(["python", "-m", module, *args]), "skipped": f"no result within {DRIVER_TIMEOUT_S:g} s"}
    return {
        "command": " ".join(["python", "-m", module, *args]),
        "exit_code": p.returncode,
        "seconds": time.monotonic() - t0,
        "output": p.stdout.rstrip(),
        "stderr_tail": p.stderr.strip().splitlines()[-5:] if p.returncode else [],
    }


# -- all of it -------------------------------------------------------------------------------------------


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
        f"  cycle time at time scale 0   {_ms(o['cycle_median_s'])}",
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
