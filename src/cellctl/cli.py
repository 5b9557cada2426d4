"""``cellctl``: the command line of the cell controller.

``serve`` runs the service; ``status``, ``command`` and ``cycle`` talk to a running service;
``align`` and the calibration commands compute in-process on the simulated cell or saved data.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import signal
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.cli_args import positive_int
from cellctl.client import CellClient, ServiceError, service_url
from cellctl.config import ConfigError, load_config
from cellctl.config.api import TokenUnavailable
from cellctl.service.compose import ServiceError as BuildError

DEFAULT_CONFIG = Path(__file__).resolve().parents[2] / "config" / "sim.toml"


def _cmd_serve(args: argparse.Namespace) -> int:
    from cellctl.service import build_service  # the composition root: imports the drivers

    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    config = load_config(args.config, read_tokens=True)  # a token it cannot read refuses the start, before anything runs

    async def run() -> int | None:
        service = await build_service(config, workdir=Path(args.workdir))
        return await service.serve(demo_cycles=args.demo_cycles)  # prints where it serves once it does

    received = asyncio.run(run())
    # Stopped cleanly either way: 0 for SIGTERM (systemd's stop), 130 for Ctrl-C as shells expect.
    return 130 if received == signal.SIGINT else 0


def _client(args: argparse.Namespace) -> CellClient:
    config = load_config(args.config)
    return CellClient(service_url(args.url, config.api.host, config.api.port), args.token)


def _cmd_status(args: argparse.Namespace) -> int:
    st = _client(args).status()
    if args.json:
        print(json.dumps(st, indent=2))
        return 0
    print(f"state {st['state']}  mode {st['mode']}  step {st['cycle_step']}  cycle {st['current_cycle']}")
    if st.get("stop_reason"):
        print(f"stop reason: {st['stop_reason']['code']} {st['stop_reason']['message']}")
    for name, d in st["devices"].items():
        age = d["heartbeat_age_s"]
        print(f"  {name:7s} {d['link']:9s} heartbeat age {'-' if age is None else f'{age:.1f} s'}")
    if st["calibration"]["problems"]:
        print("calibration: " + "; ".join(st["calibration"]["problems"]))
    job = st.get("job")
    if job:
        p = job.get("progress") or {}
        print(f"commissioning job {job['id']} ({job['procedure']}) {job['state']}: {p.get('done', 0)}/{p.get('total', '?')}"
              + (f", waiting for the engineer ({job['prompt']})" if job.get("prompt") else ""))  # fmt: skip
    print("allowed commands: " + ", ".join(st["allowed_commands"]))
    return 0


def _cmd_command(args: argparse.Namespace) -> int:
    res = _client(args).command(args.name)
    print(f"{args.name}: now {res['state']}")
    return 0


def _fmt_six(d: dict[str, Any] | None) -> str:
    if not d:
        return "-"
    keys = ("dx_mm", "dy_mm", "dz_mm", "drx_deg", "dry_deg", "drz_deg")
    return " ".join(f"{k.split('_')[0]}={d[k]:+.3f}" for k in keys if k in d)


def _cmd_cycle(args: argparse.Namespace) -> int:
    client = _client(args)
    if args.start:
        print(f"cell state: {client.bring_to_execute()}")
    failed = 0
    for k in range(args.count):
        t0 = time.monotonic()
        rec = client.start_cycle(args.recipe, f"{args.part}-{k + 1}" if args.count > 1 else args.part, key=args.key, timeout_s=args.timeout)
        if "steps" not in rec:
            print(f"cycle {rec['cycle_id']} queued (state {rec['state']}); follow it with GET /cycles/{rec['cycle_id']}")
            continue
        res = rec.get("result") or {}
        ok = rec["state"] == "done"
        failed += not ok
        line = f"cycle {rec['id']}: {rec['state']} in {time.monotonic() - t0:.1f} s"
        if ok:
            corr = res.get("correction_mm", [0, 0, 0])
            line += f"  correction {np.round(corr, 2).tolist()} mm"
        else:
            line += f"  reason: {rec['error']}"
        print(line)
        if rec.get("measured_deviation"):
            verdict = "OK" if rec.get("part_ok") else "NOT OK"
            print(f"    measured (gaps, flush): {_fmt_six(rec['measured_deviation'])}  part {verdict}")
        if rec.get("true_error"):
            print(f"    true install error: {_fmt_six(rec['true_error'])}")
    return 1 if failed else 0


def _cmd_align(args: argparse.Namespace) -> int:
    from cellctl.sim.alignment_run import simulate_alignment

    config = load_config(args.config)
    if config.mode != "sim":
        print("cellctl align runs on the simulated cell only (mode = \"sim\")", file=sys.stderr)
        return 2
    rng = np.random.default_rng(args.seed)
    print(f"simulated laser alignment, {args.runs} run(s), seed {args.seed}, config {args.config}")
    errors = []
    for k in range(args.runs):
        run = simulate_alignment(config, rng)
        res = run.result
        unc = res.wall.uncertainty
        errors.append(np.degrees(run.camera_axis_error_rad))
        print(f"run {k + 1}: spots {len(res.wall.inliers)}/{len(res.points_B)} used, fit RMS {res.wall.plane.rms:.4f} mm, "
              f"turn {np.degrees(res.rotation_rad):.3f} deg, distance {res.distance.delta_d_mm:+.3f} mm (eq. 14)")  # fmt: skip
        if unc is not None:
            print(f"    predicted normal error {np.degrees(unc.rms_rad):.4f} deg rms; true camera axis error "
                  f"{np.degrees(run.camera_axis_error_rad):.4f} deg, distance error {run.distance_error_mm:+.4f} mm")  # fmt: skip
    print(f"camera axis error vs truth: median {np.median(errors):.4f} deg, max {np.max(errors):.4f} deg")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``cellctl``."""
    parser = argparse.ArgumentParser(prog="cellctl", description="Cell controller for robotic glass installation.")
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help="TOML configuration (default: %(default)s)")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("serve", help="run the cell service (REST API, dashboard, PLC Modbus server)")
    p.add_argument("--workdir", default=".", help="where var/ (database, images, calibration) lives")
    p.add_argument("--demo-cycles", type=int, default=0, help="simulated cell: run this many cycles at start and print them")
    p.set_defaults(func=_cmd_serve)

    def remote(p: argparse.ArgumentParser) -> None:
        p.add_argument("--url", default=None, help="the running service (default: $CELLCTL_URL, else the configuration's [api])")
        p.add_argument("--token", default=None, help="bearer token (default: $CELLCTL_TOKEN)")

    p = sub.add_parser("status", help="the running cell's state, devices and calibration")
    remote(p)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_cmd_status)

    p = sub.add_parser("command", help="send a PackML command (reset, start, stop, hold, unhold, ...)")
    remote(p)
    p.add_argument("name", choices=["reset", "start", "stop", "hold", "unhold", "suspend", "unsuspend", "abort", "clear", "complete"])
    p.set_defaults(func=_cmd_command)

    p = sub.add_parser("cycle", help="run installation cycles on the running cell and print their results")
    remote(p)
    p.add_argument("--recipe", default="side-window")
    p.add_argument("--part", default="part")
    p.add_argument("--count", type=int, default=1)
    p.add_argument("--key", default=None, help="Idempotency-Key (default: a new one per cycle)")
    p.add_argument("--start", action="store_true", help="first bring the cell to Execute (clear/reset/start)")
    p.add_argument("--timeout", type=float, default=300.0)
    p.set_defaults(func=_cmd_cycle)

    p = sub.add_parser("align", help="run the laser alignment on the simulated cell in-process and score it")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--runs", type=int, default=3)
    p.set_defaults(func=_cmd_align)

    from cellctl.commissioning.cli import register as register_commissioning

    register_commissioning(sub, positive_int)
    from cellctl.bench.cli import register as register_bench
    register_bench(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``cellctl`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except (ConfigError, TokenUnavailable) as err:
        print(f"configuration refused:\n{err}", file=sys.stderr)
        return 2
    except (ServiceError, BuildError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
