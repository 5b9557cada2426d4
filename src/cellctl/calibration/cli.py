"""``cellctl calibrate camera|hand-eye|laser|nine-point|status`` and ``cellctl teach``.

Each command either runs on the cell, by default the simulated one built from the configuration
(plan, collect through the ports with a progress display, save the dataset, compute, store), or
computes offline from a saved dataset folder (``--dataset DIR``). The result goes into the
calibration store as a new version of the set; a refusal is stored too (the part becomes
"failed"), so production stays blocked until it is redone. ``--no-store`` only computes and prints.

Exit status: 0 done, 1 refused (the reason is printed), 2 usage or configuration problem.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections.abc import Awaitable, Callable
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from cellctl.calibration.calibration_set import (
    PART_NAMES,
    CalibrationSet,
    CalibrationSetError,
    CalibrationStore,
    check_ready,
    store_root,
)
from cellctl.calibration.compute import Outcome
from cellctl.calibration.dataset import Dataset, DatasetError, read_dataset
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.procedures import PROCEDURES, check_inputs
from cellctl.config import ConfigError, load_config
from cellctl.config.schema import CellConfig

METHODS = ("tsai", "opencv_tsai", "opencv_park", "opencv_horaud", "opencv_andreff", "opencv_daniilidis")


class _Progress:
    """Plain-text progress: one line per step (every tenth for long runs)."""

    def __init__(self, what: str) -> None:
        self.what = what

    def __call__(self, done: int, total: int, message: str) -> None:
        width = len(str(total))
        print(f"  [{done:>{width}}/{total}] {self.what}: {message}", flush=True)


def _store(args: argparse.Namespace, config: CellConfig) -> CalibrationStore:
    return CalibrationStore(Path(args.store) if args.store else store_root(config.calibration.directory, Path(args.workdir)))


def _now() -> datetime:
    return datetime.now(timezone.utc)


def _print_outcome(o: Outcome) -> None:
    print(f"{o.part} ({o.method}):")
    for line in o.summary:
        print(f"  {line}")
    for w in o.warnings:
        print(f"  warning: {w}")


def _twin(args: argparse.Namespace, config: CellConfig) -> Any:
    from cellctl.calibration.twin import TwinCell

    return TwinCell(config, seed=args.seed)


def _run_part(
    args: argparse.Namespace,
    part: str,
    kind: str,
    collect: Callable[[Any, CellConfig, CalibrationSet | None, Path], Awaitable[Dataset]] | None,
    compute: Callable[[Dataset, CalibrationSet | None, CellConfig], Outcome],
    method_hint: str,
) -> int:
    config = load_config(args.config)
    if args.method_override is not None:
        proc = config.calibration.procedure
        proc = proc.model_copy(update={"hand_eye": proc.hand_eye.model_copy(update={"method": args.method_override})})
        config = config.model_copy(update={"calibration": config.calibration.model_copy(update={"procedure": proc})})
    store = _store(args, config)
    try:
        current = store.current()
    except CalibrationSetError as err:
        print(f"the calibration store is damaged:\n{err}", file=sys.stderr)
        return 2
    when = _now()
    ds: Dataset | None = None
    try:
        if args.dataset:
            ds = read_dataset(args.dataset, kind)
            print(f"{part}: computing offline from {ds.root}")
        else:
            if config.mode != "sim" or collect is None:
                print(
                    f"{part}: only the simulated cell can be driven from here (mode = {config.mode!r}); "
                    "compute from a saved dataset with --dataset DIR",
                    file=sys.stderr,
                )
                return 2
            from cellctl.calibration.runs import dataset_dir

            dest = Path(args.save_dataset) if args.save_dataset else dataset_dir(store.root, kind, when)
            print(f"{part}: collecting on the simulated cell (seed {args.seed if args.seed is not None else config.sim.seed}) into {dest}")
            ds = asyncio.run(_collect(args, config, current, dest, collect))
        outcome = compute(ds, current, config)
    except CalibrationRefused as err:
        print(f"{part}: REFUSED ({err.reason}): {err.detail}")
        if not args.no_store and err.reason != "missing_input":
            from cellctl.calibration.runs import record_failure

            saved = record_failure(store, part, err, ds, config, when, method_hint)
            print(f"recorded as failed in version {saved.version} ({store.root}); production is blocked until it is redone")
        return 1
    except (DatasetError, CalibrationSetError) as err:
        print(f"{part}: {err}", file=sys.stderr)
        return 2
    _print_outcome(outcome)
    if ds is not None:
        print(f"  dataset: {ds.root}")
    if args.no_store:
        print("not stored (--no-store)")
        return 0
    from cellctl.calibration.runs import record

    saved = record(store, outcome, ds, config, when)
    print(f"stored as version {saved.version} in {store.root}")
    problems = check_ready(saved, _now())
    print("ready for production" if not problems else "still needed before production:\n  - " + "\n  - ".join(problems))
    return 0


async def _collect(
    args: argparse.Namespace,
    config: CellConfig,
    current: CalibrationSet | None,
    dest: Path,
    collect: Callable[[Any, CellConfig, CalibrationSet | None, Path], Awaitable[Dataset]],
) -> Dataset:
    twin = _twin(args, config)
    try:
        return await collect(twin, config, current, dest)
    finally:
        await twin.close()


def _procedure_command(part: str, **option_names: str) -> Callable[[argparse.Namespace], int]:
    """The CLI command running one part's procedure; ``option_names`` maps collect options to args."""
    proc = PROCEDURES[part]

    def command(args: argparse.Namespace) -> int:
        async def collect(twin: Any, config: CellConfig, cal: CalibrationSet | None, dest: Path) -> Dataset:
            check_inputs(cal, part, proc.needs)  # refuse before moving the robot when an input part is missing
            options = {opt: getattr(args, name) for opt, name in option_names.items()}
            return await proc.collect(twin, config, cal, dest, progress=_Progress(proc.kind.replace("_", " ")), **options)

        return _run_part(args, part, proc.kind, collect, proc.compute, args.method_override or proc.method)

    return command


_cmd_camera = _procedure_command("camera", views="views")
_cmd_hand_eye = _procedure_command("hand_eye", views="views")
_cmd_laser = _procedure_command("laser", poses="poses")
_cmd_nine_point = _procedure_command("pixel_map")
_cmd_teach = _procedure_command("teaching")


def _cmd_status(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    store = _store(args, config)
    try:
        cal = store.current()
        history = store.history()
    except CalibrationSetError as err:
        print(f"the calibration store is damaged:\n{err}", file=sys.stderr)
        return 2
    print(f"calibration store {store.root}: {len(history)} version(s), current {None if cal is None else cal.version}")
    if cal is not None:
        for name in PART_NAMES:
            p = cal.part(name)
            if p is None:
                print(f"  {name:10s} missing")
            else:
                print(f"  {name:10s} {p.status:6s} {p.calibrated_utc:%Y-%m-%d %H:%M} UTC  {p.id}" + (f"  ({p.failure})" if p.failure else ""))
    if args.history:
        for row in history:
            print(f"  v{row['version']:<4d} {row['created_utc']}  {row['note']}")
    problems = check_ready(cal, _now())
    print("ready for production" if not problems else "not ready:\n  - " + "\n  - ".join(problems))
    return 0 if not problems else 1


def _store_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--store", help="calibration store folder (default: calibration.directory of the configuration)")
    p.add_argument(
        "--workdir", default=".",
        help="the folder a relative calibration.directory is taken from, as `cellctl serve --workdir` (default: .)",
    )  # fmt: skip


def _common(p: argparse.ArgumentParser, *, collects: bool = True) -> None:
    _store_options(p)
    p.add_argument("--dataset", help="compute offline from this saved dataset folder instead of collecting")
    p.add_argument("--no-store", action="store_true", help="compute and print only; do not record in the store")
    if collects:
        p.add_argument("--save-dataset", help="folder for the collected dataset (default: <store>/datasets/<kind>-<time>)")
        p.add_argument("--seed", type=int, default=None, help="seed of the simulated cell (default: sim.seed)")
    p.set_defaults(method_override=None)


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``calibrate`` (camera, hand-eye, laser, nine-point, status) and ``teach`` to cellctl's parser."""
    cal = subparsers.add_parser("calibrate", help="calibrate the camera, hand-eye, laser or pixel map")
    sub = cal.add_subparsers(dest="part", required=True)

    p = sub.add_parser("camera", help="camera intrinsics by Zhang's method from checkerboard views")
    _common(p)
    p.add_argument("--views", type=int, default=None, help="number of views (default: calibration.procedure.camera.n_views)")
    p.set_defaults(func=_cmd_camera)

    p = sub.add_parser("hand-eye", help="hand-eye T_H_C (Tsai; Park, Horaud, Andreff, Daniilidis compared)")
    _common(p)
    p.add_argument("--views", type=int, default=None, help="number of views (default: calibration.procedure.camera.n_views)")
    p.add_argument("--method", dest="method_override", choices=METHODS, default=None, help="the method whose result is stored")
    p.set_defaults(func=_cmd_hand_eye)

    p = sub.add_parser("laser", help="laser origin r and direction l from a plane seen from many poses")
    _common(p)
    p.add_argument("--poses", type=int, default=None, help="number of poses (default: calibration.procedure.laser.n_poses)")
    p.set_defaults(func=_cmd_laser)

    p = sub.add_parser("nine-point", help="pixel scale (eq. 15) and the nine-point pixel-to-workpiece map")
    _common(p)
    p.set_defaults(func=_cmd_nine_point)

    p = sub.add_parser("status", help="the current calibration set, its history and whether production may start")
    _store_options(p)
    p.add_argument("--history", action="store_true", help="list every version")
    p.set_defaults(func=_cmd_status)

    t = subparsers.add_parser("teach", help="teach T0, C_Pos_0, the corner template and g_Pos_0 (paper 4.3 step 1)")
    _common(t)
    t.set_defaults(func=_cmd_teach)


__all__ = ["register", "ConfigError"]
