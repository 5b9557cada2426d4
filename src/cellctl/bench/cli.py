"""``cellctl bench accuracy``, ``cellctl bench speed`` and ``cellctl bench calibration``.

Exit status: 0 the run finished and met its targets, 1 it finished and missed a target (the
report says which), 2 a usage or configuration problem, 3 the run could not finish.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cellctl.bench.sources import ERROR_SOURCES, BenchSettingsError
from cellctl.bench.vision_args import add_arguments as add_vision_arguments
from cellctl.cli_args import non_negative_int, positive_int
from cellctl.config import CellConfig, load_config

# What a bench command's run gives: the printed report, its figures for --json, whether the targets were met.
Outcome = tuple[str, dict[str, Any], bool]


def _write_json(path: Path | None, data: dict[str, Any]) -> None:
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, allow_nan=True) + "\n", encoding="utf-8")
    print(f"figures written to {path}")


def _report(args: argparse.Namespace, text: str, figures: dict[str, Any], met: bool = True) -> int:
    """Print the report, write its figures to --json; the exit status says whether the targets were met."""
    print(text)
    _write_json(args.json, figures)
    return 0 if met else 1


def _failed(what: str, err: Exception, status: int) -> int:
    """Say on stderr why ``what`` stopped; return ``status`` (2 usage or settings, 3 the run could not finish)."""
    print(f"{what}: {err}", file=sys.stderr)
    return status


def _run(
    args: argparse.Namespace,
    what: str,
    body: Callable[[CellConfig], Outcome],
    usage: tuple[type[Exception], ...] = (),
    unfinished: tuple[type[Exception], ...] = (),
) -> int:
    """``body`` on --config, reported; a ``usage`` error exits 2, an ``unfinished`` one 3 (see :func:`_failed`)."""
    try:
        text, figures, met = body(load_config(args.config))
    except usage as err:
        return _failed(f"bench {what}", err, 2)
    except unfinished as err:
        return _failed(f"bench {what} could not finish", err, 3)
    return _report(args, text, figures, met)


def _seed_range(args: argparse.Namespace) -> range:
    """The seeds of ``--seed`` and ``--seeds``: one twin each."""
    return range(args.seed, args.seed + args.seeds)


def _cmd_accuracy(args: argparse.Namespace) -> int:
    from cellctl.bench.accuracy import BenchRunError, RunSettings, run_accuracy
    from cellctl.bench.budget import run_budget
    from cellctl.bench.plots import PlotsUnavailable, check_plots_available
    from cellctl.bench.report import format_accuracy, format_budget
    from cellctl.bench.sources import parse_off

    try:
        config = load_config(args.config)
        off = tuple(sorted(parse_off(args.off)))
        if args.budget == "parts" or _cells_mode(args):
            return _cmd_cells(args, config, off)
        if args.plots is not None:
            check_plots_available()  # refuse before the run rather than after it
        if args.budget:
            if off:
                raise BenchSettingsError("--off and --budget do not go together: the budget switches the sources itself")
            budget = run_budget(
                config, mode=args.budget, trials=args.trials, seed=args.seed, calibration=args.calibration,
                time_scale=args.time_scale, config_source=str(args.config), devices=args.devices,
                progress=not args.quiet,
            )  # fmt: skip
            print(format_budget(budget))
            _write_json(args.json, budget.as_dict())
            if args.plots is not None:
                from cellctl.bench.plots import write_budget_plot

                print(f"plot written: {write_budget_plot(budget, args.plots)}")
            return 0
        settings = RunSettings(
            args.trials, args.seed, off, args.calibration, args.time_scale, str(args.config), devices=args.devices,
            recipes=getattr(args, "recipes", "first"), via=getattr(args, "via", "orchestrator"),
        )
        run = run_accuracy(config, settings, progress=not args.quiet, workdir=args.workdir)
    except (BenchSettingsError, PlotsUnavailable) as err:
        return _failed("bench accuracy", err, 2)
    except BenchRunError as err:
        return _failed("bench accuracy could not finish", err, 3)
    print(format_accuracy(run))
    _write_json(args.json, run.as_dict())
    if args.plots is not None:
        from cellctl.bench.plots import write_accuracy_plots

        for p in write_accuracy_plots(run, args.plots):
            print(f"plot written: {p}")
    if run.workdir:
        print(f"the run's store, images and calibration set are in {run.workdir}")
    return 0 if all(a.p99_met for a in run.axes) else 1


def _cells_mode(args: argparse.Namespace) -> bool:
    """``--cells``, ``--loop`` or a drift option: the multi-cell bench (one cell when only the others are given)."""
    return args.cells is not None or args.loop is not None or args.drift_camera_deg is not None or args.drift_at is not None


def _cmd_cells(args: argparse.Namespace, config: Any, off: tuple[str, ...]) -> int:
    """``bench accuracy --cells N`` (and ``--budget parts``): many cells, each commissioned from its own data.

    Called inside :func:`_cmd_accuracy`'s ``try``, which reports its errors.
    """
    for opt, given in (("--plots", args.plots), ("--workdir", args.workdir)):
        if given is not None:
            raise BenchSettingsError(f"{opt} does not go with --cells, --loop, the drift options or --budget parts")
    if args.budget == "parts":
        from cellctl.bench.budget import run_part_budget
        from cellctl.bench.report import format_part_budget

        if args.calibration != "data" or off or args.loop is not None or args.drift_camera_deg is not None:
            raise BenchSettingsError(
                "--budget parts compares each cell's calibration from its own data with the twin's true parts: "
                "it takes --calibration data, runs with every source on and the loop off, and no drift"
            )
        budget = run_part_budget(
            config, seeds=range(args.seed, args.seed + (args.cells or 1)), trials=args.trials,
            time_scale=args.time_scale, config_source=str(args.config), devices=args.devices,
            progress=not args.quiet, calibration_cache=args.calibration_cache,
        )  # fmt: skip
        return _report(args, format_part_budget(budget), budget.as_dict())
    if args.budget:
        raise BenchSettingsError(f"--budget {args.budget} runs one cell; for many cells use --budget parts")
    from cellctl.bench.cells import CellsSettings, run_cells
    from cellctl.bench.drift import DriftSpec
    from cellctl.bench.report import format_cells

    drift = None
    if args.drift_camera_deg is not None or args.drift_at is not None:
        if args.drift_camera_deg is None or args.drift_at is None:
            raise BenchSettingsError("a drift needs both --drift-camera-deg A and --drift-at K")
        drift = DriftSpec(args.drift_camera_deg, args.drift_at, args.drift_over, args.drift_axis)
    settings = CellsSettings(
        cells=args.cells or 1, trials=args.trials, seed=args.seed, loop=args.loop or "on", settle=args.settle,
        calibration=args.calibration, off=off, time_scale=args.time_scale, config_source=str(args.config),
        devices=args.devices, drift=drift,
    )  # fmt: skip
    run = run_cells(config, settings, progress=not args.quiet, calibration_cache=args.calibration_cache)
    return _report(args, format_cells(run), run.as_dict(), run.met())


def _cmd_speed(args: argparse.Namespace) -> int:
    from cellctl.bench.speed import SpeedSettings, format_speed, run_speed

    def body(config: CellConfig) -> Outcome:
        settings = SpeedSettings(
            frames=args.frames, alignments=args.alignments, cycles=args.cycles, clients=args.clients,
            requests=args.requests, max_seconds=args.seconds, drivers=not args.no_drivers,
            abb_seconds=args.abb_seconds, seed=args.seed,
        )  # fmt: skip
        report = run_speed(config, settings, progress=not args.quiet)
        return format_speed(report), report.as_dict(), report.targets_met()

    return _run(args, "speed", body, usage=(BenchSettingsError,))


def _cmd_calibration(args: argparse.Namespace) -> int:
    from cellctl.bench.calibration import format_calibration_bench, run_calibration_bench

    def body(config: CellConfig) -> Outcome:
        parts = [p.strip() for p in args.parts.split(",") if p.strip()]
        bench = run_calibration_bench(config, _seed_range(args), parts, progress=not args.quiet)
        return format_calibration_bench(bench), bench.as_dict(), bench.bars_met()

    return _run(args, "calibration", body, usage=(ValueError,))


def _cmd_responsiveness(args: argparse.Namespace) -> int:
    from cellctl.bench.responsiveness import format_responsiveness, run_responsiveness

    def body(config: CellConfig) -> Outcome:
        figures = run_responsiveness(config, cycles=args.cycles, period_s=args.period)
        return format_responsiveness(figures), figures, True

    return _run(args, "responsiveness", body)


def _cmd_opcua(args: argparse.Namespace) -> int:
    from cellctl.bench.opcua_latency import TARGET_MS, format_opcua_latency, run_opcua_latency

    def body(config: CellConfig) -> Outcome:
        figures = run_opcua_latency(config, holds=args.holds, cycles=args.cycles, publish_ms=args.publish_ms)
        met = all(figures[k].get("max_ms", 0.0) <= TARGET_MS for k in ("state", "cycle_step"))
        return format_opcua_latency(figures), figures, met

    return _run(args, "opcua", body)


def _cmd_cycle_time(args: argparse.Namespace) -> int:
    from cellctl.bench.accuracy import BenchRunError
    from cellctl.bench.cycle_time import format_cycle_time, run_cycle_time

    def body(config: CellConfig) -> Outcome:
        figures = run_cycle_time(config, cells=args.cells, trials=args.trials, seed=args.seed, progress=not args.quiet)
        return format_cycle_time(figures), figures, bool(figures["bar_met"])

    return _run(args, "cycle-time", body, unfinished=(BenchRunError,))


def _cmd_arc_corner(args: argparse.Namespace) -> int:
    from cellctl.bench.arc_corner import format_arc_corner, run_arc_corner_bench
    from cellctl.bench.arc_corner_twin import format_arc_corner_twin, run_arc_corner_twin

    def body(config: CellConfig) -> Outcome:
        t0 = time.perf_counter()
        if args.renderer == "twin":
            twin = run_arc_corner_twin(args.renders, args.seed, args.config, args.radius_mm)
            return format_arc_corner_twin(twin, time.perf_counter() - t0), twin, bool(twin["bar_met"])
        figures = run_arc_corner_bench(args.renders, args.seed)
        return format_arc_corner(figures, time.perf_counter() - t0), figures, bool(figures["bar_met"])

    return _run(args, "arc-corner", body)


def _cmd_soak(args: argparse.Namespace) -> int:
    from cellctl.bench.accuracy import BenchRunError
    from cellctl.bench.soak import SoakSettings, format_soak, run_soak

    def body(config: CellConfig) -> Outcome:
        settings = SoakSettings(
            cycles=args.cycles, seed=args.seed, calibration=args.calibration, image_bound_mb=args.image_bound_mb,
            status_requests=args.status_requests, time_scale=args.time_scale,
        )  # fmt: skip
        report = run_soak(config, settings, progress=not args.quiet, workdir=args.workdir)
        return format_soak(report), report.as_dict(), report.disk_held

    return _run(args, "soak", body, usage=(BenchSettingsError,), unfinished=(BenchRunError,))


def _cmd_verify(args: argparse.Namespace) -> int:
    from cellctl.bench.verify import format_verify_bench, run_verify_bench

    def body(config: CellConfig) -> Outcome:
        bench = run_verify_bench(config, _seed_range(args), progress=not args.quiet)
        return format_verify_bench(bench, config), bench.as_dict(), bench.passed()

    return _run(args, "verify", body)


def _cmd_vision(args: argparse.Namespace) -> int:
    from cellctl.bench.vision import run

    return run(args)


_positive_int = positive_int
_seed = non_negative_int


def _report_options(p: argparse.ArgumentParser, json_help: str = "write the figures to this JSON file") -> None:
    p.add_argument("--json", type=Path, default=None, help=json_help)
    p.add_argument("--quiet", action="store_true", help="no progress display")


def _seed_option(p: argparse.ArgumentParser, help_text: str | None = None) -> None:
    p.add_argument("--seed", type=_seed, default=1, help=help_text)


def _seeds_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seeds", type=_positive_int, default=20, help="how many twins (default 20)")
    _seed_option(p, "the first seed (default 1)")


def _calibration_option(p: argparse.ArgumentParser, help_text: str) -> None:
    """``--calibration data|oracle``: computed from simulated data (the default) or the twin's truth."""
    p.add_argument("--calibration", choices=["data", "oracle"], default="data", help=help_text)


def _run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--time-scale", type=float, default=None, help="override sim.time_scale (real s per simulated s)")
    p.add_argument("--workdir", type=Path, default=None, help="keep the run's store and images here (new or empty folder)")


def _command(sub: Any, name: str, func: Callable[[argparse.Namespace], int], **texts: str) -> argparse.ArgumentParser:
    """The sub-command ``name`` (``help``, ``description``), run by ``func``."""
    p = sub.add_parser(name, **texts)
    p.set_defaults(func=func)
    return p


def _options(p: argparse.ArgumentParser, rows: tuple[tuple[str, Callable[[str], Any], Any, str], ...]) -> None:
    """Plain options, one (flag, type, default, help) each."""
    for flag, kind, default, text in rows:
        p.add_argument(flag, type=kind, default=default, help=text)


def register(subparsers: Any) -> None:
    """Add ``bench accuracy``, ``speed``, ``calibration`` and ``verify`` to ``cellctl``'s sub-commands."""
    bench = subparsers.add_parser("bench", help="benchmarks: install accuracy (the paper's experiment), speed, calibration")
    sub = bench.add_subparsers(dest="bench_command", required=True)

    p = _command(
        sub, "accuracy", _cmd_accuracy,
        help="N install cycles of the simulated cell at random postures, scored against the truth",
        description="Runs the paper's experiment (section 5.3) in the simulated cell through the orchestrator and "
        "prints per axis max |error|, mean, std and p99 beside the paper's figures and the tolerance.",
    )
    p.add_argument("--trials", type=_positive_int, default=20, help="install cycles (default 20, as the paper)")
    _seed_option(p, "the twin's seed: postures and every error source (default 1)")
    _report_options(p, "write every trial and figure to this JSON file")
    p.add_argument("--plots", type=Path, default=None, help="write PNG plots (paper Figs. 5 and 6) into this folder")
    p.add_argument(
        "--recipes", choices=["first", "mix"], default="first",
        help="first: every trial installs the configuration's first recipe (default); mix: each trial's recipe drawn at "
        "random (seeded) from [[process.recipes]], with per-recipe figures",
    )  # fmt: skip
    p.add_argument(
        "--via", choices=["orchestrator", "plc"], default="orchestrator",
        help="orchestrator: each cycle submitted to the cell's orchestrator (default); plc: requested by a line PLC "
        "over Modbus TCP on loopback (recipe_id, the handshake of docs/plc_register_map.md)",
    )  # fmt: skip
    p.add_argument(
        "--off", default=None,
        help=f"error sources to switch off, comma-separated: {', '.join(ERROR_SOURCES)} (or all)",
    )  # fmt: skip
    _calibration_option(
        p, "data: the calibration set computed from simulated data (default); oracle: the twin's true mountings"
    )
    p.add_argument(
        "--budget", nargs="?", const="alone-on", choices=["alone-on", "alone-off", "parts"], default=None,
        help="error budget: run the same trials with each source alone on (default) or alone off, and show which "
        "source dominates each axis; parts: per cell (--cells), each calibration part swapped for the twin's truth, "
        "and the part behind each axis's bias",
    )  # fmt: skip
    p.add_argument(
        "--cells", type=_positive_int, default=None,
        help="run this many simulated cells (seeds --seed, --seed+1, ...), each commissioned from its own simulated "
        "data, --trials cycles each; pooled and per-cell figures",
    )  # fmt: skip
    p.add_argument(
        "--loop", choices=["on", "off", "both"], default=None,
        help="with --cells: the closed loop (process.spc) on (default), off, or both side by side on the same cells",
    )
    p.add_argument("--settle", type=_seed, default=20, help="with --cells: cycles before a cell's settled mean (default 20)")
    p.add_argument(
        "--drift-camera-deg", type=float, default=None,
        help="with --cells: turn the twin's camera mount by this angle (deg) from cycle --drift-at",
    )  # fmt: skip
    _options(p, (
        ("--drift-at", _positive_int, None, "the cycle the drift starts at (1-based)"),
        ("--drift-over", _positive_int, 1, "spread the drift linearly over this many cycles"),
    ))
    p.add_argument(
        "--drift-axis", choices=["x", "y", "z"], default="x",
        help="the camera's own axis the mount turns about (default x: the optical axis tilts along the image's v)",
    )  # fmt: skip
    p.add_argument(
        "--calibration-cache", type=Path, default=None,
        help="with --cells or --budget parts: keep each cell's commissioned calibration set here and reuse it",
    )  # fmt: skip
    p.add_argument(
        "--devices", choices=["twin", "config"], default="twin",
        help="twin: the twin's in-process devices (default); config: the devices of --config (in config/sim.toml "
        "the real drivers against their protocol fakes)",
    )  # fmt: skip
    _run_options(p)

    p = _command(
        sub, "speed", _cmd_speed,
        help="vision, alignment, cycle compute overhead, GET /status under load, driver figures",
        description="Medians and ratios of the cell's compute: corner detection per frame (vs cv2.Canny), "
        "compute_alignment, the cycle's compute overhead, GET /status latency under concurrent load, and the "
        "driver packages' own benchmarks.",
    )
    _options(p, (
        ("--frames", _positive_int, 30, "timed corner detections (default 30)"),
        ("--alignments", _positive_int, 200, "timed compute_alignment calls (default 200)"),
        ("--cycles", _positive_int, 15, "cycles for the compute overhead (default 15)"),
        ("--clients", _positive_int, 16, "concurrent GET /status clients (default 16)"),
        ("--requests", _positive_int, 2000, "GET /status requests per phase (default 2000)"),
        ("--seconds", float, 20.0, "time bound of each /status phase (default 20 s)"),
        ("--abb-seconds", float, 5.0, "python -m abb_robot.bench --seconds (default 5)"),
    ))
    p.add_argument("--no-drivers", action="store_true", help="leave out the driver packages' benchmarks")
    _seed_option(p)
    _report_options(p)

    p = _command(
        sub, "vision", _cmd_vision,
        help="the corner detector against the twin's truth: clean, real openings (seal, flange, marks, dirt), disturbances",
        description="The corner detector's accuracy and acceptance per case against the twin's truth, and its time "
        "against cv2.Canny on the same frame (as python -m cellctl.bench.vision).",
    )
    add_vision_arguments(p)

    p = _command(
        sub, "calibration", _cmd_calibration,
        help="commissioning calibrations on one twin per seed, compared with the twin's true mountings",
        description="Runs the calibration procedures (as `cellctl calibrate` does) on --seeds simulated cells and "
        "prints each figure per seed, its median and worst beside the bar it must meet.",
    )
    _seeds_options(p)
    p.add_argument(
        "--parts", default="laser",
        help="comma-separated: laser, camera, hand_eye (default laser; camera and hand_eye render board views)",
    )  # fmt: skip
    _report_options(p)

    p = _command(
        sub, "verify", _cmd_verify,
        help="calibrate verify on one twin per seed: quiet when nothing moved, an alarm when the camera moved",
        description="Calibrates camera, hand-eye and laser on --seeds simulated cells, then runs `cellctl calibrate verify` "
        "unchanged and with the twin's camera moved on the flange (0.3 mm + 0.05 deg, 0.3 mm, 0.05 deg).",
    )
    _seeds_options(p)
    _report_options(p)

    p = _command(
        sub, "soak", _cmd_soak,
        help="N cycles of the simulated cell service: RSS, disk per cycle, GET /status latency, retention held",
        description="Runs N install cycles through the simulated cell service's orchestrator with a small image "
        "bound, and prints RSS, disk use per cycle (images, database) and GET /status latency at start and end, "
        "and whether the images stayed under the bound (exit 1 if not).",
    )
    p.add_argument("--cycles", type=_positive_int, default=1000, help="install cycles (default 1000)")
    _seed_option(p, "the twin's seed (default 1)")
    _calibration_option(
        p, "data: the calibration set the cell computes from simulated data at start (default); oracle: the twin's truth"
    )
    _options(p, (
        ("--image-bound-mb", float, 50.0, "the retention's image bound for the run (default 50 MB)"),
        ("--status-requests", _positive_int, 300, "GET /status requests at start and end (default 300)"),
    ))
    _run_options(p)
    _report_options(p)

    p = _command(
        sub, "responsiveness", _cmd_responsiveness,
        help="PLC and REST response times while the simulated cell commissions itself and installs windows",
    )
    _options(p, (
        ("--cycles", _positive_int, 20, "windows installed after commissioning (default 20)"),
        ("--period", float, 0.05, "seconds between two requests of each client (default 0.05)"),
    ))
    _report_options(p)

    p = _command(
        sub, "cycle-time", _cmd_cycle_time,
        help="stop and go against reading the wall on the move: cycle time and accuracy on the same cells",
    )
    _options(p, (
        ("--cells", _positive_int, 3, "twins (one seed each; default 3)"),
        ("--trials", _positive_int, 10, "install cycles per twin and mode (default 10)"),
    ))
    _seed_option(p, "the first twin's seed (default 1)")
    _report_options(p)

    p = _command(
        sub, "arc-corner", _cmd_arc_corner,
        help="the large-radius corner (the arc as the feature) on renders with known truth: centre error, refusals",
    )
    _options(p, (("--renders", _positive_int, 200, "rendered frames (default 200)"),))
    p.add_argument("--renderer", choices=("own", "twin"), default="own",
                   help="own: the bench's clean arcs with glare, occluders, wrong radii; twin: the twin's door window (default own)")
    p.add_argument("--radius-mm", type=float, default=None,
                   help="with --renderer twin: the door window's corner radius (default the recipe's 150 mm), measured by the "
                   "method that radius gives (the corner method up to about 58 mm, else the arc)")
    _seed_option(p, "the renders' seed (default 1)")
    _report_options(p)

    p = _command(sub, "opcua", _cmd_opcua, help="how soon an encrypted OPC UA client sees a state or step change of the cell")
    _options(p, (
        ("--holds", _positive_int, 20, "Hold/Unhold pairs (4 state changes each; default 20)"),
        ("--cycles", _positive_int, 5, "cycles run after them (a CycleStep change per sub-step; default 5)"),
        ("--publish-ms", float, 10.0, "the client's publishing interval in ms (default 10)"),
    ))
    _report_options(p)
