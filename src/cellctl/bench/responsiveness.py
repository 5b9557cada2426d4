"""``cellctl bench responsiveness``: how long the PLC and the REST API wait while the cell computes.

The service answers the line PLC (Modbus TCP) and the REST API on the same event loop that runs
commissioning jobs and cycles; computation (rendering in the twin, board and corner detection,
calibration fits, PNG encoding) belongs in worker threads, so no request should wait for it.
This benchmark starts the simulated cell from an empty calibration set, so it commissions itself
(camera, hand-eye, laser, teaching and nine-point as jobs, the heaviest computation the cell
does), then installs windows; throughout, a Modbus client reads the cell's register block and an
HTTP client asks ``GET /status``, each every ``period_s``, and the report gives their response
times per phase (median, p95, p99, max) and how many took over 100 ms.
"""

from __future__ import annotations

import asyncio
import statistics
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

from cellctl.bench.accuracy import bring_to_execute
from cellctl.config import CellConfig, parse_config
from cellctl.plc.register_map import CELL_BLOCK
from cellctl.store import CycleRequest

SLOW_S = 0.1


@dataclass
class Series:
    """Response times (s) of one kind of request in one phase."""

    times: list[float] = field(default_factory=list)
    failures: int = 0

    def figures(self) -> dict[str, float | int]:
        t = sorted(self.times)
        if not t:
            return {"requests": 0, "failures": self.failures}

        def q(p: float) -> float:
            return t[min(len(t) - 1, int(round(p * (len(t) - 1))))] * 1000.0

        return {"requests": len(t), "failures": self.failures, "median_ms": statistics.median(t) * 1000.0,
                "p95_ms": q(0.95), "p99_ms": q(0.99), "max_ms": t[-1] * 1000.0, "over_100ms": sum(v > SLOW_S for v in t)}  # fmt: skip


def _config(base: CellConfig) -> CellConfig:
    data = base.model_dump(mode="json")
    data["plc"].update(enabled=True, host="127.0.0.1", port=0)
    data["opcua"].update(enabled=False)
    data["calibration"].update(source="set", auto_calibrate_in_sim=True, directory="var/calibration")
    data["store"]["path"] = "var/cellctl.db"
    return parse_config(data, "bench responsiveness")


async def _run(config: CellConfig, cycles: int, period_s: float, workdir: Path) -> dict[str, dict[str, Any]]:
    from pymodbus.client import AsyncModbusTcpClient

    from cellctl.api.app import create_app
    from cellctl.service import build_service

    service = await build_service(config, workdir=workdir)
    await service.start()
    phases: dict[str, dict[str, Series]] = {}
    phase = "commissioning"
    stop = asyncio.Event()
    app = create_app(service.orchestrator, config.api, service.jobs)

    def series(kind: str) -> Series:
        return phases.setdefault(phase, {}).setdefault(kind, Series())

    async def poll_rest() -> None:
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://cell") as client:
            while not stop.is_set():
                t0 = time.perf_counter()
                try:
                    r = await client.get("/status")
                    r.raise_for_status()
                    series("rest_status").times.append(time.perf_counter() - t0)
                except Exception:  # noqa: BLE001 - counted, the run goes on
                    series("rest_status").failures += 1
                await asyncio.sleep(period_s)

    async def poll_plc() -> None:
        port = service.plc_server.port  # type: ignore[union-attr]
        client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=5, retries=0)
        await client.connect()
        try:
            while not stop.is_set():
                t0 = time.perf_counter()
                try:
                    rr = await client.read_holding_registers(CELL_BLOCK.start, count=CELL_BLOCK.size, device_id=config.plc.unit_id)
                    if rr.isError():
                        raise RuntimeError(str(rr))
                    series("plc_read").times.append(time.perf_counter() - t0)
                except Exception:  # noqa: BLE001 - counted, the run goes on
                    series("plc_read").failures += 1
                await asyncio.sleep(period_s)
        finally:
            client.close()

    pollers = [asyncio.create_task(poll_rest()), asyncio.create_task(poll_plc())]
    try:
        await service.ready_for_production()
        phase = "production"
        orch = service.orchestrator
        await bring_to_execute(orch)
        recipe = next(iter(config.process.recipe_names().values()))
        for k in range(cycles):
            sub = await orch.submit_cycle(CycleRequest(recipe, f"resp-{k}", None, source="bench"), scope="bench", key=f"r{k}", actor="bench")
            await orch.wait_cycle(sub.cycle.id, 600.0)
    finally:
        stop.set()
        await asyncio.gather(*pollers, return_exceptions=True)
        await service.stop()
    return {p: {k: s.figures() for k, s in kinds.items()} for p, kinds in phases.items()}


def run_responsiveness(config: CellConfig, *, cycles: int = 20, period_s: float = 0.05) -> dict[str, dict[str, Any]]:
    """Commission the simulated cell and install ``cycles`` windows while timing PLC and REST requests."""
    with tempfile.TemporaryDirectory(prefix="cellctl-bench-responsiveness-") as tmp:
        return asyncio.run(_run(_config(config), cycles, period_s, Path(tmp)))


def format_responsiveness(figures: dict[str, dict[str, Any]]) -> str:
    lines = ["PLC (Modbus read of the cell block) and REST (GET /status) response times, by phase", "",
             f"{'phase':14s} {'request':12s} {'n':>6s} {'median ms':>10s} {'p95 ms':>8s} {'p99 ms':>8s} {'max ms':>8s} {'>100 ms':>8s} {'failed':>7s}"]  # fmt: skip
    for phase, kinds in figures.items():
        for kind, f in kinds.items():
            if not f.get("requests"):
                lines.append(f"{phase:14s} {kind:12s} {0:>6d} {'-':>10s}")
                continue
            lines.append(f"{phase:14s} {kind:12s} {f['requests']:>6d} {f['median_ms']:10.1f} {f['p95_ms']:8.1f} {f['p99_ms']:8.1f} "
                         f"{f['max_ms']:8.1f} {f['over_100ms']:>8d} {f['failures']:>7d}")  # fmt: skip
    return "\n".join(lines)

