"""``cellctl bench soak``: N install cycles of the simulated cell service, watching memory, disk and /status.

The run goes the way production goes (as :mod:`cellctl.bench.accuracy`): the composition root
builds the service with its store, images and retention task, the cell commissions itself (or
takes the twin's truth), is brought to Execute, and each cycle is submitted to the orchestrator
under an idempotency key. The retention's image bound is set small (``--image-bound-mb``) so
that it is reached during the run: the images folder must stay under it.

Figures, at the start (after the first cycle, so caches are warm) and at the end:

- the process's resident memory (RSS; flat over the run is the aim);
- disk per cycle: the image bytes each cycle wrote (from its record's files), and the database's
  growth per cycle (pages in use, so a write-ahead log that has not been checkpointed does not
  count twice), with the tables that grow (SQLite's ``dbstat``, where available);
- GET /status latency: median and p95 of ``--status-requests`` sequential requests through the
  service's own ASGI app in-process (the HTTP stack without the socket), with the cell idle;
- the retention: the bound, the largest images folder seen after any cycle, the folder after
  the last pass, images pruned.

Exit status (cli): 0 when the images stayed under their bound (a finished cycle's images may
overshoot it until the pass that cycle triggers: one cycle's worth is allowed), 1 otherwise.
"""

from __future__ import annotations

import asyncio
import contextlib
import statistics
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from cellctl.bench.accuracy import (
    ACTOR,
    BenchRunError,
    bring_to_execute,
    prepare_calibration,
)
from cellctl.bench.progress import Progress
from cellctl.bench.sources import (
    BenchSettingsError,
    CalibrationMode,
    DevicesMode,
    run_config,
    run_workdir,
)
from cellctl.bench.stats import percentile
from cellctl.cell.orchestrator import CycleRefused
from cellctl.config import CellConfig, parse_config
from cellctl.domain import PackMLState
from cellctl.store import CycleRequest, CycleState

MB = 1024**2


@dataclass(frozen=True)
class SoakSettings:
    """What a soak run was asked to do."""

    cycles: int = 1000
    seed: int = 1
    calibration: CalibrationMode = "data"
    image_bound_mb: float = 50.0
    status_requests: int = 300
    samples: int = 10
    time_scale: float | None = None
    devices: DevicesMode = "twin"

    def __post_init__(self) -> None:
        if self.cycles < 2:
            raise BenchSettingsError(f"--cycles must be at least 2 (one warms up), got {self.cycles}")
        if not self.image_bound_mb > 0:
            raise BenchSettingsError(f"--image-bound-mb must be above 0, got {self.image_bound_mb}")
        if self.status_requests < 1:
            raise BenchSettingsError(f"--status-requests must be at least 1, got {self.status_requests}")


@dataclass(frozen=True)
class Snapshot:
    """The process and the disk after ``cycles`` cycles."""

    cycles: int
    wall_s: float
    rss_mb: float | None
    images_mb: float
    images_count: int
    database_file_mb: float  # the database with its -wal and -shm files
    database_used_mb: float  # pages in use
    status_ms: dict[str, float] | None = None  # median, p95, max of GET /status


@dataclass
class SoakReport:
    settings: SoakSettings
    start: Snapshot
    end: Snapshot
    samples: list[Snapshot]
    outcomes: dict[str, int]
    image_bytes_per_cycle: float
    database_bytes_per_cycle: float
    table_bytes_per_cycle: dict[str, float] | None
    bound_mb: float
    peak_images_mb: float
    final_images_mb: float
    largest_cycle_images_mb: float
    pruned_images: int
    recoveries: int
    cycle_time_s: dict[str, float]
    wall_s: float
    notes: list[str] = field(default_factory=list)

    @property
    def rss_growth_mb_per_100_cycles(self) -> float | None:
        if self.start.rss_mb is None or self.end.rss_mb is None or self.end.cycles <= self.start.cycles:
            return None
        return (self.end.rss_mb - self.start.rss_mb) / (self.end.cycles - self.start.cycles) * 100

    @property
    def rss_trend_mb_per_100_cycles(self) -> float | None:
        """The least-squares slope of RSS over the second half of the run (a one-off step early on,
        an allocator arena or a cache filling, does not count; a leak does)."""
        pts = [(s.cycles, s.rss_mb) for s in [*self.samples, self.end] if s.rss_mb is not None and s.cycles >= self.end.cycles / 2]
        if len(pts) < 3:
            return None
        mx = statistics.fmean(x for x, _ in pts)
        my = statistics.fmean(y for _, y in pts)
        sxx = sum((x - mx) ** 2 for x, _ in pts)
        return None if sxx == 0 else sum((x - mx) * (y - my) for x, y in pts) / sxx * 100  # type: ignore[operator]

    @property
    def disk_held(self) -> bool:
        """The images stayed under the bound, give or take the one cycle whose pass had not run yet."""
        return self.final_images_mb <= self.bound_mb and self.peak_images_mb <= self.bound_mb + self.largest_cycle_images_mb

    def as_dict(self) -> dict[str, Any]:
        return {
            "benchmark": "soak",
            "settings": asdict(self.settings),
            "start": asdict(self.start),
            "end": asdict(self.end),
            "samples": [asdict(s) for s in self.samples],
            "outcomes": self.outcomes,
            "per_cycle": {
                "images_kb": self.image_bytes_per_cycle / 1024,
                "database_kb": self.database_bytes_per_cycle / 1024,
                "tables_kb": None if self.table_bytes_per_cycle is None
                else {k: v / 1024 for k, v in self.table_bytes_per_cycle.items()},
            },  # fmt: skip
            "rss_growth_mb_per_100_cycles": self.rss_growth_mb_per_100_cycles,
            "rss_trend_mb_per_100_cycles": self.rss_trend_mb_per_100_cycles,
            "retention": {
                "bound_mb": self.bound_mb,
                "peak_images_mb": self.peak_images_mb,
                "final_images_mb": self.final_images_mb,
                "largest_cycle_images_mb": self.largest_cycle_images_mb,
                "pruned_images": self.pruned_images,
                "held": self.disk_held,
            },
            "recoveries": self.recoveries,
            "cycle_time_s": self.cycle_time_s,
            "wall_s": self.wall_s,
            "notes": self.notes,
        }


def rss_mb() -> float | None:
    """The process's resident set now (Linux /proc), None where that cannot be read."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def soak_config(base: CellConfig, settings: SoakSettings, workdir: Path) -> CellConfig:
    """The benchmark run's configuration (:func:`run_config`) with the retention's image bound set small."""
    cfg = run_config(
        base, workdir=workdir, seed=settings.seed, calibration=settings.calibration, time_scale=settings.time_scale,
        devices=settings.devices,
    )  # fmt: skip
    data = cfg.model_dump(mode="json")
    data["store"]["retention"].update(enabled=True, images_max_gb=settings.image_bound_mb / 1024)
    return parse_config(data, "soak benchmark configuration")


async def _status_latency(client: Any, n: int) -> dict[str, float]:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        r = await client.get("/status")
        times.append((time.perf_counter() - t0) * 1000)
        if r.status_code != 200:
            raise BenchRunError(f"GET /status answered {r.status_code}: {r.text[:200]}")
    return {"median": statistics.median(times), "p95": percentile(times, 95), "max": max(times), "n": float(n)}


async def _run_async(config: CellConfig, settings: SoakSettings, workdir: Path, progress: Progress) -> SoakReport:
    import httpx

    from cellctl.api.app import create_app
    from cellctl.service import build_service
    from cellctl.service.retention import StorageRetention
    from cellctl.service.retention_plan import scan_images

    t0 = time.monotonic()
    service = await build_service(config, workdir=workdir)
    await service.start()
    notes: list[str] = []
    try:
        orch = service.orchestrator
        retention = service.extras.get("retention")
        if not isinstance(retention, StorageRetention):
            raise BenchRunError("the service has no retention task (cellctl.service.retention)")
        image_dir = orch.image_dir
        progress.message(f"soak: preparing the calibration ({settings.calibration}) ...")
        await prepare_calibration(service, 3600.0)
        await bring_to_execute(orch)
        recipe = next(iter(config.process.recipe_names().values()))
        app = create_app(orch, config.api, service.jobs)

        async def snapshot(k: int, with_status: bool) -> Snapshot:
            files = await asyncio.to_thread(scan_images, image_dir)
            size = await orch.store.database_size()
            status = await _status_latency(client, settings.status_requests) if with_status else None
            return Snapshot(
                cycles=k, wall_s=time.monotonic() - t0, rss_mb=rss_mb(),
                images_mb=sum(f.size for f in files.values()) / MB, images_count=len(files),
                database_file_mb=retention.database_bytes() / MB, database_used_mb=size.used_bytes / MB,
                status_ms=status,
            )  # fmt: skip

        outcomes = {"done": 0, "failed": 0, "refused": 0, "interrupted": 0, "timeout": 0}
        written: list[int] = []
        times: list[float] = []
        peak = 0.0
        recoveries = 0
        samples: list[Snapshot] = []
        every = max(1, settings.cycles // max(1, settings.samples))
        start: Snapshot | None = None
        db_start = None
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://cell") as client:
            for k in range(1, settings.cycles + 1):
                if orch.machine.state is not PackMLState.EXECUTE:
                    recoveries += 1
                    await bring_to_execute(orch)
                key = f"soak-{settings.seed}-{k}"
                try:
                    sub = await orch.submit_cycle(CycleRequest(recipe, f"soak-{k}", car_id=key, source=ACTOR),
                                                  scope=ACTOR, key=key, actor=ACTOR)  # fmt: skip
                except CycleRefused as err:
                    outcomes["refused"] += 1
                    notes.append(f"cycle {k} refused: {err.reason}")
                    continue
                record = await orch.wait_cycle(sub.cycle.id, 300.0)
                state = record.state
                outcome = {CycleState.DONE: "done", CycleState.FAILED: "failed", CycleState.INTERRUPTED: "interrupted"}
                outcomes[outcome.get(state, "timeout")] += 1
                if state not in outcome:
                    notes.append(f"cycle {k}: no result within 300 s; the run stopped there")
                    break
                if state is CycleState.FAILED and len(notes) < 20:
                    notes.append(f"cycle {k} failed: {(record.error or '')[:120]}")
                if record.result and record.result.get("cycle_time_s") is not None:
                    times.append(float(record.result["cycle_time_s"]))
                n = 0
                for img in record.images:
                    try:
                        n += (image_dir / img.uri).stat().st_size
                    except OSError:
                        pass
                written.append(n)
                files = await asyncio.to_thread(scan_images, image_dir)
                peak = max(peak, sum(f.size for f in files.values()) / MB)
                if k == 1:
                    start = await snapshot(k, with_status=True)
                    db_start = await orch.store.database_size(per_table=True)
                elif k % every == 0 and k != settings.cycles:
                    samples.append(await snapshot(k, with_status=False))
                progress.advance(state.value)
            await retention.run_once()  # the last cycle's pass, so the final figure is what retention keeps
            end = await snapshot(sum(outcomes[o] for o in ("done", "failed", "interrupted")), with_status=True)
        if start is None or db_start is None:
            raise BenchRunError("the first cycle did not finish; nothing to compare")
        db_end = await orch.store.database_size(per_table=True)
        span = max(1, end.cycles - start.cycles)
        tables = None
        if db_start.tables is not None and db_end.tables is not None:
            tables = {
                t: (db_end.tables.get(t, 0) - db_start.tables.get(t, 0)) / span
                for t in sorted(set(db_start.tables) | set(db_end.tables))
                if db_end.tables.get(t, 0) != db_start.tables.get(t, 0)
            }
        pruned = int(retention.status()["pruned_since_start"]["images"])
    finally:
        await service.stop()
    return SoakReport(
        settings=settings,
        start=start,
        end=end,
        samples=samples,
        outcomes=outcomes,
        image_bytes_per_cycle=statistics.fmean(written) if written else 0.0,
        database_bytes_per_cycle=(db_end.used_bytes - db_start.used_bytes) / span,
        table_bytes_per_cycle=tables,
        bound_mb=settings.image_bound_mb,
        peak_images_mb=peak,
        final_images_mb=end.images_mb,
        largest_cycle_images_mb=max(written, default=0) / MB,
        pruned_images=pruned,
        recoveries=recoveries,
        cycle_time_s={"median": percentile(times, 50), "p95": percentile(times, 95)} if times else {},
        wall_s=time.monotonic() - t0,
        notes=notes,
    )



def _workdir(keep: Path | None) -> contextlib.AbstractContextManager[Path]:
    return run_workdir(keep, "cellctl-soak-")


def run_soak(base: CellConfig, settings: SoakSettings, *, progress: bool = True, workdir: Path | None = None) -> SoakReport:
    """Run ``settings.cycles`` cycles of the simulated cell service; see the module docstring."""
    bar = Progress("soak cycles", settings.cycles, enabled=progress)
    with _workdir(workdir) as wd:
        config = soak_config(base, settings, wd)
        return asyncio.run(_run_async(config, settings, wd, bar))


def format_soak(r: SoakReport) -> str:
    """The report as text."""

    def ms(s: Snapshot) -> str:
        if s.status_ms is None:
            return "-"
        return f"median {s.status_ms['median']:.2f} ms, p95 {s.status_ms['p95']:.2f} ms, max {s.status_ms['max']:.1f} ms"

    def rss(v: float | None) -> str:
        return "n/a" if v is None else f"{v:.1f} MB"

    growth, trend = r.rss_growth_mb_per_100_cycles, r.rss_trend_mb_per_100_cycles
    lines = [
        f"soak: {r.settings.cycles} cycles of the simulated cell (seed {r.settings.seed}, calibration "
        f"{r.settings.calibration}) in {r.wall_s:.0f} s; outcomes: "
        + ", ".join(f"{k} {v}" for k, v in r.outcomes.items() if v),
        "",
        f"{'':24}{'start (after cycle ' + str(r.start.cycles) + ')':>28}{'end (after cycle ' + str(r.end.cycles) + ')':>28}",
        f"{'RSS':24}{rss(r.start.rss_mb):>28}{rss(r.end.rss_mb):>28}",
        f"{'images on disk':24}{f'{r.start.images_mb:.1f} MB ({r.start.images_count})':>28}"
        f"{f'{r.end.images_mb:.1f} MB ({r.end.images_count})':>28}",
        f"{'database (files)':24}{f'{r.start.database_file_mb:.2f} MB':>28}{f'{r.end.database_file_mb:.2f} MB':>28}",
        f"{'database (pages used)':24}{f'{r.start.database_used_mb:.2f} MB':>28}{f'{r.end.database_used_mb:.2f} MB':>28}",
        f"GET /status at start: {ms(r.start)}",
        f"GET /status at end:   {ms(r.end)}  ({r.settings.status_requests} sequential requests, in-process ASGI)",
        "",
        f"RSS growth: {'n/a' if growth is None else f'{growth:+.2f} MB per 100 cycles'} from start to end; "
        f"trend over the second half: {'n/a (too few samples)' if trend is None else f'{trend:+.2f} MB per 100 cycles'}",
        f"disk per cycle: images {r.image_bytes_per_cycle / 1024:.0f} kB written, database {r.database_bytes_per_cycle / 1024:.1f} kB",
    ]
    if r.table_bytes_per_cycle:
        lines.append("  database growth per cycle by table: " + ", ".join(
            f"{t} {v / 1024:.2f} kB" for t, v in sorted(r.table_bytes_per_cycle.items(), key=lambda kv: -kv[1])
        ))  # fmt: skip
    if r.cycle_time_s:
        lines.append(f"cycle time: median {r.cycle_time_s['median']:.2f} s, p95 {r.cycle_time_s['p95']:.2f} s")
    lines += [
        f"retention: images bound {r.bound_mb:g} MB; largest folder after a cycle {r.peak_images_mb:.1f} MB "
        f"(one cycle writes up to {r.largest_cycle_images_mb:.2f} MB), after the last pass {r.final_images_mb:.1f} MB; "
        f"{r.pruned_images} images pruned: {'held' if r.disk_held else 'NOT HELD'}",
    ]
    if r.samples:
        lines.append("samples (cycle: RSS, images, database used): " + "; ".join(
            f"{s.cycles}: {rss(s.rss_mb)}, {s.images_mb:.1f} MB, {s.database_used_mb:.2f} MB" for s in r.samples
        ))  # fmt: skip
    if r.recoveries:
        lines.append(f"the cell was brought back to Execute {r.recoveries} times")
    lines += [f"note: {n}" for n in r.notes]
    return "\n".join(lines)


__all__ = ["SoakReport", "SoakSettings", "Snapshot", "format_soak", "run_soak", "soak_config", "rss_mb"]
