"""Benchmark: the driver's CPU time per exchange against the exchange's wire time.

The fake controller runs in a child process, so this process's CPU time (``time.process_time``)
is the driver's alone: the event loop, the serial I/O system calls, framing, parsing and the
reply bookkeeping of one ``read()``. The wire time is what the same exchange takes on a real
RS-232C line: (request + reply bytes) x 10 bits / baud. The target is a CPU share under 10 %.

Run: ``python -m keyence_lkg.bench [--count 3000] [--baud 115200]``.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import multiprocessing as mp
import os
import statistics
import tempfile
import time
from dataclasses import dataclass

from keyence_lkg.driver import KeyenceLkgSensor
from keyence_lkg.errors import DIALECTS
from keyence_lkg.fake import FakeLkgController

TARGET_SHARE = 0.10
_counter = 0


def _moving_target() -> float:
    """A distance that changes every reading (so each reply differs), within the LK-G500's range."""
    global _counter
    _counter += 1
    return 350.0 + 80.0 * math.sin(_counter * 0.001)


def _serve_fake(dialect: str, link_path: str, ready: mp.synchronize.Event, stop: mp.synchronize.Event) -> None:
    with FakeLkgController(dialect, _moving_target, link_path=link_path, display_unit="0.001mm"):
        ready.set()
        stop.wait()


@dataclass(frozen=True)
class BenchResult:
    """Medians over the measured exchanges of one dialect."""

    dialect: str
    count: int
    cpu_us: float
    cpu_p90_us: float
    wall_us: float
    bytes_per_exchange: float
    wire_us: float

    @property
    def share(self) -> float:
        """Driver CPU time as a fraction of the wire time."""
        return self.cpu_us / self.wire_us


async def _measure(dialect: str, path: str, count: int, baud: int) -> BenchResult:
    sensor = KeyenceLkgSensor(
        port=path,
        dialect=dialect,
        display_unit="0.001mm",
        reference_distance_mm=350.0,
        displacement_positive="away_from_head",
        exchange_timeout_s=1.0,
    )
    try:
        for _ in range(200):  # warm up: first open, caches, allocator
            await sensor.read(timeout_s=2.0)
        cpu, wall, nbytes = [], [], []
        for _ in range(count):
            w0, r0 = sensor.bytes_on_wire
            c0 = time.process_time_ns()
            t0 = time.perf_counter_ns()
            reading = await sensor.read(timeout_s=2.0)
            t1 = time.perf_counter_ns()
            c1 = time.process_time_ns()
            w1, r1 = sensor.bytes_on_wire
            if reading.distance_mm is None:
                raise RuntimeError(f"benchmark reading has no value: {reading}")
            cpu.append((c1 - c0) / 1e3)
            wall.append((t1 - t0) / 1e3)
            nbytes.append((w1 - w0) + (r1 - r0))
        if sensor.stats.resyncs or sensor.stats.garbled_lines or sensor.stats.timeouts:
            raise RuntimeError(f"the benchmark link was not clean: {sensor.stats}")
    finally:
        await sensor.close()
    per_exchange = statistics.median(nbytes)
    return BenchResult(
        dialect=dialect,
        count=count,
        cpu_us=statistics.median(cpu),
        cpu_p90_us=statistics.quantiles(cpu, n=10)[-1],
        wall_us=statistics.median(wall),
        bytes_per_exchange=per_exchange,
        wire_us=per_exchange * 10 / baud * 1e6,
    )


def run(dialect: str, count: int, baud: int) -> BenchResult:
    """Start the fake in a child process, measure ``count`` reads, stop the fake."""
    ctx = mp.get_context("spawn")
    with tempfile.TemporaryDirectory(prefix="lkg-bench-") as tmp:
        link = os.path.join(tmp, "ttyLKG0")
        ready, stop = ctx.Event(), ctx.Event()
        child = ctx.Process(target=_serve_fake, args=(dialect, link, ready, stop), daemon=True)
        child.start()
        try:
            if not ready.wait(20.0):
                raise RuntimeError("the fake controller did not start within 20 s")
            return asyncio.run(_measure(dialect, link, count, baud))
        finally:
            stop.set()
            child.join(10.0)
            if child.is_alive():
                child.kill()


def main(argv: list[str] | None = None) -> int:
    """Print the medians and the CPU share of the wire time per dialect."""
    parser = argparse.ArgumentParser(prog="python -m keyence_lkg.bench", description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=3000, help="measured exchanges per dialect")
    parser.add_argument("--baud", type=int, default=115200, help="baud rate for the wire time")
    parser.add_argument("--dialect", choices=DIALECTS, action="append", help="default: both")
    args = parser.parse_args(argv)
    if args.count < 10:
        parser.error("--count must be at least 10")
    dialects = args.dialect or list(DIALECTS)
    print(f"LK-G driver over a pseudo-terminal, fake in a child process; {args.count} reads each; "
          f"wire time at {args.baud} baud, 10 bits a byte")
    print(f"{'dialect':9} {'CPU/exchange':>13} {'CPU p90':>9} {'wall':>9} {'bytes':>6} {'wire':>9} {'CPU/wire':>9}")
    worst = 0.0
    for dialect in dialects:
        r = run(dialect, args.count, args.baud)
        worst = max(worst, r.share)
        print(f"{r.dialect:9} {r.cpu_us:10.1f} us {r.cpu_p90_us:6.1f} us {r.wall_us:6.1f} us "
              f"{r.bytes_per_exchange:6.0f} {r.wire_us:6.1f} us {100 * r.share:8.1f} %")
    verdict = "met" if worst < TARGET_SHARE else "NOT met"
    print(f"target: driver CPU under {100 * TARGET_SHARE:.0f} % of the wire time: {verdict} (worst {100 * worst:.1f} %)")
    return 0 if worst < TARGET_SHARE else 1


if __name__ == "__main__":
    raise SystemExit(main())
