"""``cellctl bench speed``, GET /status latency under load.

``cellctl serve``'s real service (uvicorn on loopback, in its own process) and N concurrent httpx
clients, bounded in count and time; once with the cell idle, once while it runs cycles.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import multiprocessing as mp
import os
import socket
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cellctl.bench.progress import Progress
from cellctl.bench.sources import run_config
from cellctl.bench.stats import percentile
from cellctl.config import CellConfig, parse_config

if TYPE_CHECKING:
    from cellctl.bench.speed import SpeedSettings


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
