"""``cellctl``: the command line of the cell controller.

``serve`` runs the service; ``status``, ``command``, ``cycle`` and ``parts`` talk to a running service;
``align`` and the calibration commands compute in-process on the simulated cell or saved data.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import select
import shlex
import signal
import sys
import tempfile
import time
from collections.abc import Iterable
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from pydantic import ValidationError

from cellctl.cli_args import (
    WORKDIR_ENV,
    CliParser,
    add_remote_options,
    default_workdir,
    non_negative_int,
    port_number,
    positive_int,
    positive_number,
    remote_client,
)
from cellctl.client import CellClient, ServiceError
from cellctl.config import CellConfig, ConfigError, load_config
from cellctl.config.api import TokenUnavailable
from cellctl.config.loader import check_tokens, format_validation_errors
from cellctl.logsetup import FORMATS, LEVELS, JsonFormatter, configure_logging
from cellctl.service.errors import ServiceClockBehind, ServiceConfigError
from cellctl.service.errors import ServiceError as BuildError
from cellctl.store.records import StoreError

CONFIG_ENV = "CELLCTL_CONFIG"
_CHECKOUT_CONFIG = Path(__file__).resolve().parents[2] / "config" / "sim.toml"  # a source checkout's one copy
_PACKAGED_CONFIG = Path(__file__).resolve().parent / "data" / "sim.toml"  # the same file, installed with the package


def default_config() -> Path:
    """``$CELLCTL_CONFIG``, else the simulated cell's configuration: config/sim.toml of a source checkout, or the
    copy installed with the package (``pip install .`` puts it in cellctl/data)."""
    if os.environ.get(CONFIG_ENV):
        return Path(os.environ[CONFIG_ENV])
    return _CHECKOUT_CONFIG if _CHECKOUT_CONFIG.is_file() else _PACKAGED_CONFIG


def cellctl_version() -> str:
    """The installed distribution's version (pyproject.toml is its one source)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("cellctl")
    except PackageNotFoundError:  # run from a tree that was never installed
        return "unknown (not installed)"


DEFAULT_CONFIG = default_config()


class UsageError(ValueError):
    """A bad option value found after parsing; ``main`` prints it on one line and exits 2 (as argparse does)."""


def _with_api_options(config: CellConfig, args: argparse.Namespace) -> CellConfig:
    """The configuration with ``serve --host/--port`` in [api], validated again as a whole (the file's rules, e.g.
    that [api], [plc] and [opcua] each have their own port, hold for the options too); ConfigError names them."""
    given = {k: v for k, v in (("host", args.host), ("port", args.port)) if v is not None}
    if not given:
        return config
    data = config.model_dump()
    data["api"] |= given
    options = " ".join(f"--{k} {shlex.quote(str(v))}" for k, v in given.items())
    try:
        return CellConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(format_validation_errors(f"{args.config} with serve {options}", err)) from None


def _cmd_serve(args: argparse.Namespace) -> int:
    from cellctl.service import build_service  # the composition root: imports the drivers

    config = _with_api_options(load_config(args.config), args)
    workdir = Path(args.workdir)  # relative token, password and TLS files from it, as every other path
    api, opcua = config.api.rooted(workdir), config.opcua.rooted(workdir)
    if api is not config.api or opcua is not config.opcua:
        config = config.model_copy(update={"api": api, "opcua": opcua})
    check_tokens(config, str(args.config))  # a token it cannot read refuses the start, before anything runs

    async def run() -> int | None:
        service = await build_service(config, workdir=workdir)
        return await service.serve(demo_cycles=args.demo_cycles)  # prints where it serves once it does

    received = asyncio.run(run())
    # Stopped cleanly either way: 0 for SIGTERM (systemd's stop), 130 for Ctrl-C as shells expect.
    return 130 if received == signal.SIGINT else 0


def _client(args: argparse.Namespace, config: CellConfig | None = None) -> CellClient:
    return remote_client(args, config or load_config(args.config))


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
    print(f"{args.name}: now {res['state']}" + (f" ({res['effect']})" if res.get("effect") else ""))
    return 0


def _fmt_six(d: dict[str, Any] | None) -> str:
    if not d:
        return "-"
    keys = ("dx_mm", "dy_mm", "dz_mm", "drx_deg", "dry_deg", "drz_deg")
    return " ".join(f"{k.split('_')[0]}={d[k]:+.3f}" for k in keys if k in d)


def _cmd_cycle(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    client = _client(args, config)
    recipe = args.recipe or config.default_recipe  # the configuration's first, as teach and nine-point take
    if args.start:
        print(f"cell state: {client.bring_to_execute()}")
    failed = 0
    for k in range(args.count):
        t0 = time.monotonic()
        rec = client.start_cycle(recipe, f"{args.part}-{k + 1}" if args.count > 1 else args.part, key=args.key, timeout_s=args.timeout)
        if "steps" not in rec:
            print(f"cycle {rec['cycle_id']} queued (state {rec['state']}); follow it with GET /cycles/{rec['cycle_id']}")
            continue
        res = rec.get("result") or {}
        ok = rec["state"] == "done"
        failed += not ok
        took = res.get("cycle_time_s")  # the record's, on the cell's clock (the robot time; simulated in simulation)
        line = f"cycle {rec['id']}: {rec['state']}, " + (f"cycle time {took:.1f} s" if isinstance(took, (int, float))
                                                         else f"{time.monotonic() - t0:.1f} s after the request")
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


TIME_HELP = "ISO 8601 with a timezone, e.g. 2025-03-01T06:00:00+01:00 or 2025-03-01T05:00:00Z"


def _moment(option: str, text: str | None) -> datetime | None:
    """An option's date and time; a bad or naive one raises UsageError naming the option and the format."""
    if text is None:
        return None
    try:
        t = datetime.fromisoformat(text)
    except ValueError:
        raise UsageError(f"{option}: {text!r} is not a date and time; give {TIME_HELP}") from None
    if t.tzinfo is None:
        raise UsageError(f"{option}: {text!r} has no timezone; give {TIME_HELP}")
    return t


def write_json_lines(out: TextIO, items: Iterable[dict[str, Any]]) -> int:
    """One compact JSON object per line; returns how many."""
    n = 0
    for item in items:
        out.write(json.dumps(item, ensure_ascii=False, separators=(",", ":")) + "\n")
        n += 1
    return n


def write_json_lines_atomically(path: Path, items: Iterable[dict[str, Any]]) -> int:
    """:func:`write_json_lines` to a temporary file beside ``path``, renamed over it once complete (a reader never
    sees half an export; a failure leaves ``path`` as it was)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            n = write_json_lines(f, items)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return n


OPEN_END = datetime(9999, 12, 31, tzinfo=timezone.utc)
"""The ``until`` sent without ``--until``: the cell applies its own bound (its latest install's end), whatever this
host's clock says, and answers it (the next export's ``--since``)."""


def _cmd_parts_export(args: argparse.Namespace) -> int:
    since = _moment("--since", args.since)
    until = _moment("--until", args.until)
    if since is not None and until is not None and until <= since:
        raise UsageError(f"--until ({until.isoformat()}) must be later than --since ({since.isoformat()})")
    until = until or OPEN_END
    bound = [until.isoformat()]  # the cell may apply an earlier bound: it answers the bound it applied
    installs = _client(args).parts(car_id=args.car_id, since=since, until=until, applied=lambda b: bound.__setitem__(0, b))
    if args.output == "-":
        try:
            n = write_json_lines(sys.stdout, installs)
            sys.stdout.flush()
        except BrokenPipeError:  # the reader stopped (e.g. `| head`): no traceback, no count
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 1
        where = "standard output"
    else:
        out = Path(args.output)
        try:
            n = write_json_lines_atomically(out, installs)
        except OSError as err:
            print(f"error: cannot write {out}: {err.strerror or err}", file=sys.stderr)
            return 1
        where = str(out)
    print(f"wrote {n} part install{'s' if n != 1 else ''} (ended {args.since} to {bound[0]}) to {where}", file=sys.stderr)
    return 0


def _cmd_parts_show(args: argparse.Namespace) -> int:
    history = _client(args).part(args.part_id)
    installs = history["installs"]
    print(f"glass {history['part_id']}: {len(installs)} install{'s' if len(installs) != 1 else ''}")
    for i in installs:
        verdict = "running" if i["ok"] is None else "OK" if i["ok"] else f"NOT OK ({i['error_code']}: {i['reason']})"
        took = "" if i["cycle_time_s"] is None or i["state"] == "interrupted" else f" in {i['cycle_time_s']:.1f} s"
        print(f"cycle {i['cycle_id']}: {i['state']} {verdict}{took}; car {i['car_id'] or '-'}, recipe {i['recipe']} "
              f"({i.get('recipe_settings') or '-'}), calibration set {i['calibration_version'] or '-'}, ended {i['finished_at'] or i['interrupted_at'] or '-'}")  # fmt: skip
        print(f"    measured (gaps, flush): {_fmt_six(i['measured_deviation'])}")
        steps = ", ".join(
            f"{s['step']} {'ok' if s['ok'] else 'open' if s['ok'] is None else 'FAILED'}"
            + ("" if s["duration_s"] is None else f" {s['duration_s']:.2f} s")
            for s in i["steps"]
        )
        print(f"    steps: {steps or '-'}")
        for im in i["images"]:
            digest = (im["sha256"] or "-")[:16]
            print(f"    image {im['name']} ({im['step']}): {im['status']}, sha256 {digest}..., {im['size_bytes'] or '-'} bytes")
        for a in i["actions"]:
            print(f"    {a['at']} {a['actor']} ({a['source']}): {a['action']}"
                  + (f" {a['state_before']} -> {a['state_after']}" if a["state_before"] != a["state_after"] else ""))  # fmt: skip
        for al in i["alarms"]:
            ack = f"acknowledged by {al['ack_by']} at {al['ack_at']}" if al["ack_by"] else "not acknowledged"
            print(f"    alarm {al['code']} {al['message']} raised {al['raised_at']}, {ack}")
    return 0


def _cmd_align(args: argparse.Namespace) -> int:
    from cellctl.align.errors import AlignmentError
    from cellctl.sim.alignment_run import simulate_alignment
    from cellctl.sim.robot import ReachError

    config = load_config(args.config)
    if config.mode != "sim":
        print("cellctl align runs on the simulated cell only (mode = \"sim\")", file=sys.stderr)
        return 2
    rng = np.random.default_rng(args.seed)
    print(f"simulated laser alignment, {args.runs} run(s), seed {args.seed}, config {args.config}")
    errors = []
    for k in range(args.runs):
        try:
            run = simulate_alignment(config, rng)
        except (AlignmentError, ReachError) as err:  # refused: its message says what and what to change
            print(f"cellctl align: run {k + 1} refused: {err}", file=sys.stderr)
            return 1
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


def _global_options(p: argparse.ArgumentParser, top: bool) -> None:
    """``--config``, ``--log-level`` and ``--log-format``: before the command, or after it (``cellctl status --config F``)."""
    keep = argparse.SUPPRESS  # given after the command it overrides; absent it leaves the value before the command
    p.add_argument("--config", type=Path, default=default_config() if top else keep,
                   help=f"TOML configuration (default: ${CONFIG_ENV}, else the simulated cell's, {default_config()})")  # fmt: skip
    p.add_argument("--log-level", choices=LEVELS, type=str.lower, default=None if top else keep,
                   help="least severe log messages shown on stderr (default: $CELLCTL_LOG_LEVEL, else warning)")  # fmt: skip
    p.add_argument("--log-format", choices=FORMATS, default=None if top else keep,
                   help="text, or json: one JSON object per line (ts, level, logger, message, exc_info) "
                        "(default: $CELLCTL_LOG_FORMAT, else text)")  # fmt: skip


def _leaf_parsers(parser: argparse.ArgumentParser) -> Iterable[argparse.ArgumentParser]:
    """Every parser below ``parser`` that has no sub-commands of its own."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):  # aliases share a parser
                subs = [a for a in child._actions if isinstance(a, argparse._SubParsersAction)]
                yield from _leaf_parsers(child) if subs else (child,)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``cellctl``."""
    parser = CliParser(prog="cellctl", description="Cell controller for robotic glass installation.")
    parser.add_argument("--version", action="version", version=f"cellctl {cellctl_version()}")
    _global_options(parser, top=True)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("serve", help="run the cell service (REST API, dashboard, PLC Modbus server)")
    p.add_argument("--workdir", type=Path, default=default_workdir(),
                   help=f"where var/ (database, images, calibration) lives (default: ${WORKDIR_ENV}, else the current folder)")  # fmt: skip
    p.add_argument("--host", default=None, help="address the REST API listens on (default: the configuration's [api] host)")
    p.add_argument("--port", type=port_number, default=None, help="the REST API's TCP port (default: the configuration's [api] port)")
    p.add_argument("--demo-cycles", type=non_negative_int, default=0, metavar="N",
                   help="simulated cell: run this many cycles at start and print them")  # fmt: skip
    p.set_defaults(func=_cmd_serve)

    p = sub.add_parser("status", help="the running cell's state, devices and calibration")
    add_remote_options(p)
    p.add_argument("--json", action="store_true", help="print the service's status document as JSON")
    p.set_defaults(func=_cmd_status)

    p = sub.add_parser("command", help="send a PackML command (reset, start, stop, hold, unhold, ...)")
    add_remote_options(p)
    p.add_argument("name", choices=["reset", "start", "stop", "hold", "unhold", "suspend", "unsuspend", "abort", "clear", "complete"],
                   help="the PackML command")  # fmt: skip
    p.set_defaults(func=_cmd_command)

    p = sub.add_parser("cycle", help="run installation cycles on the running cell and print their results")
    add_remote_options(p)
    p.add_argument("--recipe", default=None, help="the recipe each cycle installs (a name of [[process.recipes]]; default: the first)")
    p.add_argument("--part", default="part", help="the glass's part id; with --count N, -1 ... -N are appended (default: %(default)s)")
    p.add_argument("--count", type=positive_int, default=1, metavar="N", help="how many cycles to run one after the other (default: 1)")
    p.add_argument("--key", default=None, help="Idempotency-Key (default: a new one per cycle)")
    p.add_argument("--start", action="store_true", help="first bring the cell to Execute (clear/reset/start)")
    p.add_argument("--timeout", type=positive_number, default=300.0, metavar="SECONDS",
                   help="longest wait for one cycle's result (default: %(default)g s)")  # fmt: skip
    p.set_defaults(func=_cmd_cycle)

    p = sub.add_parser("parts", help="part traceability: every install of a glass or car body, for the MES")
    parts = p.add_subparsers(dest="parts_command", required=True, metavar="SUBCOMMAND")
    p = parts.add_parser("export", help="write the installs that ended in a window as JSON lines (GET /parts documents)")
    add_remote_options(p)
    p.add_argument("--since", required=True, metavar="ISO", help=f"installs that ended at or after this time ({TIME_HELP})")
    p.add_argument("--until", default=None, metavar="ISO", help="installs that ended before this time (default: the cell's latest install end; "
                   "the bound applied is in the count line: the next export's --since)")
    p.add_argument("--car-id", default=None, metavar="CAR_ID", help="only this car body's installs")
    p.add_argument("--output", default="-", metavar="FILE", help="file to write (replaced atomically), or - for standard output (default)")
    p.set_defaults(func=_cmd_parts_export)
    p = parts.add_parser("show", help="a readable summary of every install of one glass")
    add_remote_options(p)
    p.add_argument("part_id", help="the glass's part id, any characters ('/' too; after -- when it begins with -)")
    p.set_defaults(func=_cmd_parts_show)

    p = sub.add_parser("align", help="run the laser alignment on the simulated cell in-process and score it")
    p.add_argument("--seed", type=non_negative_int, default=1, help="random seed of the simulated cell (default: %(default)s)")
    p.add_argument("--runs", type=positive_int, default=3, metavar="N", help="how many alignments (default: %(default)s)")
    p.set_defaults(func=_cmd_align)

    from cellctl.cli_config import register as register_config

    register_config(sub)
    from cellctl.commissioning.cli_parser import register as register_commissioning

    register_commissioning(sub, positive_int)
    from cellctl.bench.cli import register as register_bench

    register_bench(sub)
    for leaf in _leaf_parsers(parser):
        _global_options(leaf, top=False)
    return parser


CLOCK_BEHIND = ("This computer's clock stands behind the certificate's start (started before NTP set the clock, or a "
                "flat RTC battery): exit 1, so systemd starts the service again (deploy/cellctl.service: "
                "Restart=on-failure, within its start limit) and it comes up once the clock is right; enable "
                "systemd-time-wait-sync.service or chrony-wait.service so that it waits for the clock (README, Deployment)")
"""What `serve` adds when a certificate it presents is not valid yet (:class:`ServiceClockBehind`)."""

SIGPIPE_EXIT = 128 + signal.SIGPIPE
"""The exit status when the reader of standard output stopped (`cellctl config check | head -1`): quiet, as a
Unix tool ended by SIGPIPE."""


def stdout_closed() -> bool:
    """Whether standard output is a pipe or socket whose reader has gone."""
    try:
        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
        return any(ev & (select.POLLERR | select.POLLHUP) for _, ev in poll.poll(0))
    except (OSError, ValueError):  # no descriptor (replaced stdout)
        return False


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``cellctl`` console script (and ``python -m cellctl``)."""
    args = build_parser().parse_args(argv)
    try:
        handler = configure_logging(args.log_level, args.log_format)
    except ValueError as err:  # $CELLCTL_LOG_LEVEL or $CELLCTL_LOG_FORMAT
        print(f"cellctl: error: {err}", file=sys.stderr)
        return 2
    as_json = isinstance(handler.formatter, JsonFormatter)

    def refuse(text: str) -> None:  # with JSON logs a refusal is one JSON record too (a log pipeline reads stderr)
        if as_json:
            logging.getLogger("cellctl").error(text)
        else:
            print(text, file=sys.stderr)

    try:
        rc = int(args.func(args))
        sys.stdout.flush()  # a reader that stopped (`| head`) shows here, not in a message at exit
        return rc
    except (ConfigError, TokenUnavailable) as err:
        refuse(f"configuration refused:\n{err}")
        return 2
    except ServiceConfigError as err:  # a file the configuration names, found unusable at start: a restart cannot help
        refuse(f"error: {err}")
        return 2
    except ServiceClockBehind as err:  # a certificate not valid yet: the clock stands behind, a restart once it is right cures it
        refuse(f"error: {err}. {CLOCK_BEHIND}")
        return 1
    except (ServiceError, BuildError, StoreError) as err:  # StoreError: a database file serve cannot use, named
        refuse(f"error: {err}")
        return 1
    except UsageError as err:
        refuse(f"error: {err}")
        return 2
    except OSError as err:  # a file or socket the command needs: one line, no traceback
        if isinstance(err, BrokenPipeError) and stdout_closed():  # our reader stopped: nothing to say to it
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # nor at exit's flush
            return SIGPIPE_EXIT
        logging.getLogger("cellctl").debug("command failed", exc_info=True)
        refuse(f"error: {err}")
        return 1
    except Exception:
        if not as_json:
            raise
        logging.getLogger("cellctl").critical("cellctl stopped on an unexpected error", exc_info=True)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
