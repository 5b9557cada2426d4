"""``cellctl calibrate camera|hand-eye|laser|nine-point|verify|status`` and ``cellctl teach``.

A procedure runs as a job of the running service (``cellctl serve``), on the cell's own devices:
the command starts it over REST, follows it on the event stream with a progress bar, shows each
prompt and sends the engineer's answer, and prints the result (the job stores a new version of
the calibration set when the result passes its gates). ``--dry-run`` prints the plan and moves
nothing; Ctrl-C cancels the job (the robot stops at once). ``--dataset DIR`` instead computes
offline, in this process, from a saved dataset and records the result in the store folder (not
when it is the part in use again: the same dataset, the same values); it names the parts it builds on.
The version it stores names its writer (the OS account, ``cli:offline``, the dataset), and so does a
``calibration.store`` entry in the cell's audit log (:mod:`cellctl.calibration.provenance`).

Exit status: 0 done, 1 refused, failed or cancelled (or a verification found drift), 2 usage or
configuration problem, 130 cancelled with Ctrl-C. The parser of these commands is
:mod:`cellctl.commissioning.cli_parser` (light: ``cellctl``'s other commands need not import these).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable, Iterator
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from cellctl.calibration.calibration_set import (
    PART_NAMES,
    CalibrationSet,
    CalibrationSetError,
    CalibrationStore,
    parts_of,
    store_root,
)
from cellctl.calibration.provenance import offline_writer
from cellctl.calibration.dataset import DatasetError, read_dataset
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.readiness import check_ready
from cellctl.cli_args import WORKDIR_ENV, remote_client
from cellctl.client import CellClient
from cellctl.commissioning.registry import ALL_PROCEDURES
from cellctl.config import load_config

if TYPE_CHECKING:
    from cellctl.calibration.compute import Outcome
    from cellctl.calibration.set_parts import PartRecord
    from cellctl.config.schema import CellConfig
    from cellctl.store import CellStore


def _client(args: argparse.Namespace) -> CellClient:
    return remote_client(args, load_config(args.config))


def _options(args: argparse.Namespace, procedure: str) -> dict[str, Any]:
    opts: dict[str, Any] = {}
    if getattr(args, "views", None) is not None:
        opts["views"] = args.views
    if getattr(args, "poses", None) is not None:
        opts["poses"] = args.poses
    if getattr(args, "method_override", None) is not None:
        opts["method"] = args.method_override
    if getattr(args, "recipe", None) is not None:
        opts["recipe"] = args.recipe
    if getattr(args, "no_store", False):
        opts["store"] = False
    return opts


def _store(args: argparse.Namespace) -> CalibrationStore:
    config = load_config(args.config)
    return CalibrationStore(Path(args.store) if args.store else store_root(config.calibration.directory, Path(args.workdir)))


SAME_TOL = 1e-9  # relative, and absolute in the part's units (px, mm, rad): a recompute within it is the same part
# A camera's K and dist: the same lens when no ray of the image lands further than SAME_LENS_PX from where it did. The
# last bits of an LM fit are not the same everywhere (OpenCV on a thread pool, as an earlier release ran it, put the
# same views' rays up to 3.5e-6 px apart; another PC's CPU may too); the twin camera's std of fx and cx is 0.4 px and
# its corners' RMS 0.03 px: 1e-4 px lies 4000 and 300 times below them, and any change of views or settings moves more.
SAME_LENS_PX = 1e-4


def _close(a: Any, b: Any) -> bool:
    """Equal values, numbers within SAME_TOL (dicts and lists walked)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool) and not isinstance(b, bool):
        return math.isclose(a, b, rel_tol=SAME_TOL, abs_tol=SAME_TOL)
    return bool(a == b)


def _same_part(p: PartRecord | None, outcome: Outcome, sha: str) -> bool:
    """``p`` (the part in use) was computed from the dataset with manifest SHA-256 ``sha``, by the same method from
    the same parts, and ``outcome`` recomputed its values within SAME_TOL (a camera: SAME_LENS_PX): storing it would
    change nothing but its id."""
    values = getattr(p, "values", None)
    if p is None or p.status != "ok" or values is None or p.dataset is None or p.dataset.manifest_sha256 != sha:
        return False
    if p.method != outcome.method or p.inputs != outcome.inputs:
        return False
    try:
        fresh = type(values).model_validate(outcome.values)
    except ValidationError:
        return False  # not a valid part: recording it says why
    a, b = values.model_dump(), fresh.model_dump()
    if outcome.part == "camera":
        from cellctl.calibration.camera import lens_shift_px

        shift = lens_shift_px(a.pop("K"), a.pop("dist"), b.pop("K"), b.pop("dist"), a["image_size"])
        return shift <= SAME_LENS_PX and _close(a, b)  # nan (not a lens) is not the same
    return _close(a, b)


def _sets(store: CalibrationStore, cal: CalibrationSet | None) -> Iterator[CalibrationSet]:
    """The set in use, then the store's other versions, newest first (a damaged one left out: it cannot say)."""
    if cal is not None:
        yield cal
    for v in reversed(store.versions()):
        if cal is None or v != cal.version:
            try:
                yield store.load(v)
            except (CalibrationSetError, OSError):
                continue


def _made_from(store: CalibrationStore, cal: CalibrationSet | None, name: str, recipe: str | None, sha: str) -> PartRecord | None:
    """The newest part ``name`` (``recipe``'s own, if it names one) computed from the dataset with manifest SHA-256 ``sha``:
    the set in use's, else the newest in the history (None: none recorded)."""
    for one in _sets(store, cal):
        p = one.part(name, recipe)
        if p is not None and p.status == "ok" and p.dataset is not None and p.dataset.manifest_sha256 == sha:
            return p
    return None


def _say_inputs(outcome: Outcome, recorded: PartRecord | None) -> None:
    """Which parts of the set in use the result was computed with, and which the part stored from the dataset was."""
    for dep, used in outcome.inputs.items():
        print(f"  computed with {dep} {used} (the set in use)")
        then = None if recorded is None else recorded.inputs.get(dep)
        if recorded is not None and then is not None and then != used:
            print(f"  note: this dataset gave {outcome.part} {recorded.id}, computed with {dep} {then}; this result is "
                  f"computed with {dep} {used} instead, so it differs from that one by the change of {dep}")


def _offline(args: argparse.Namespace, procedure: str) -> int:
    """Compute from a saved dataset in this process; store the result unless --no-store."""
    from cellctl.calibration.recording import record

    config = load_config(args.config)
    if args.method_override is not None:
        proc_cfg = config.calibration.procedure
        proc_cfg = proc_cfg.model_copy(update={"hand_eye": proc_cfg.hand_eye.model_copy(update={"method": args.method_override})})
        config = config.model_copy(update={"calibration": config.calibration.model_copy(update={"procedure": proc_cfg})})
    proc = ALL_PROCEDURES[procedure]
    store = _store(args)
    try:
        current = store.current()
        ds = read_dataset(Path(os.path.abspath(args.dataset)), proc.kind)  # the set names it relative to the store if in it
        cell, config = config, config.for_recipe(ds.manifest.get("recipe") or config.default_recipe)  # a recipe's dataset: its settings
    except (CalibrationSetError, DatasetError, KeyError) as err:
        print(f"{procedure}: {err}", file=sys.stderr)
        return 2
    if (foreign := _other_cell(ds.manifest.get("source"), cell, args.accept_cell)) is not None:
        print(f"{procedure}: {foreign}", file=sys.stderr)
        return 2
    print(f"{procedure}: computing offline from {ds.root}")
    try:
        if procedure == "verify":  # its reference datasets: beside it, else in the store it is computed against
            from cellctl.commissioning.verify import compute_verify

            outcome = compute_verify(ds, current, config, store_root=store.root)
        else:
            outcome = proc.compute(ds, current, config)
    except CalibrationRefused as err:
        print(f"{procedure}: REFUSED ({err.reason}): {err.detail}")
        print("nothing stored: the calibration set in use is unchanged")
        return 1
    except DatasetError as err:
        print(f"{procedure}: {err}", file=sys.stderr)
        return 2
    print(f"{outcome.part} ({outcome.method}):")
    for line in outcome.summary:
        print(f"  {line}")
    for w in outcome.warnings:
        print(f"  warning: {w}")
    if procedure == "verify":
        print(f"  dataset: {ds.root}")
        return 0 if outcome.quality.get("passed") else 1
    sha = ds.ref().manifest_sha256
    _say_inputs(outcome, _made_from(store, current, outcome.part, outcome.recipe, sha) if outcome.inputs else None)
    print(f"  dataset: {ds.root}")
    if args.no_store:
        print("not stored (--no-store)")
        return 0
    in_use = None if current is None else current.part(outcome.part, outcome.recipe)
    if in_use is not None and _same_part(in_use, outcome, sha):
        label = outcome.part + (f" of recipe {outcome.recipe}" if outcome.recipe is not None else "")
        print(f"identical to the {label} in use ({in_use.id}); not stored: the calibration set in use is unchanged")
        return 0
    audit = _audit_log(args, cell, store)
    if isinstance(audit, str):
        print(f"{procedure}: not stored: {audit}", file=sys.stderr)
        return 1
    when = datetime.now(timezone.utc)
    try:
        saved = record(store, outcome, ds, config, when, note=f"{outcome.part}: computed offline from {ds.root}",
                       measured=ds.measured_utc, written_by=offline_writer(ds, store.root))  # validity from the capture, not today
    except CalibrationSetError as err:  # the store busy with another writer, or its set in use damaged
        print(f"{procedure}: not stored: {err}", file=sys.stderr)
        if audit is not None:
            audit.close()
        return 1
    print(f"stored as version {saved.version} in {store.root}")
    rc = _audit_store(procedure, audit, saved, outcome, store, args)
    if ds.measured_utc is not None and when - ds.measured_utc > timedelta(hours=1):
        print(f"  calibrated as of the dataset's capture, {ds.measured_utc:%Y-%m-%d %H:%M} UTC: its validity runs from then")
    problems = check_ready(saved, when, recipe=ds.manifest.get("recipe"), first_recipe=cell.default_recipe, config=cell,
                           store_root=store.root)
    print("ready for production" if not problems else "still needed before production:\n  - " + "\n  - ".join(problems))
    return rc


def _other_cell(source: object, config: CellConfig, accepted: str | None) -> str | None:
    """Why a dataset its manifest says another cell (or mode) recorded may not calibrate this one; None if it may. Its
    poses and images are that cell's: a hand-eye from them is that camera's mounting. ``--accept-cell NAME`` takes
    one recorded on cell NAME (e.g. this cell under its former cell_id)."""
    src = source if isinstance(source, dict) else {}
    cell, mode = src.get("cell"), src.get("mode")
    if cell is not None and cell != config.cell_id and cell != accepted:
        return (f"the dataset was recorded on cell {cell!r}, this configuration is cell_id {config.cell_id!r}: its poses "
                f"and images calibrate that cell, not this one; record this cell's own (without --dataset), or if it is "
                f"this cell under a former cell_id, give --accept-cell {cell}")
    if mode is not None and mode != config.mode:
        return (f"the dataset was recorded in mode {mode!r} (the simulated cell's or a real one's), this configuration is "
                f"mode {config.mode!r}: record this cell's own (without --dataset)")
    return None


def _audit_log(args: argparse.Namespace, config: CellConfig, store: CalibrationStore) -> CellStore | str | None:
    """The cell's store to audit a new version of ``store`` in: the cell's own calibration folder (calibration.directory
    under --workdir) is audited in its [store] path (None: another folder, not the cell's); a str: why it cannot be."""
    from cellctl.calibration.provenance import open_audit_log
    from cellctl.store import StoreError

    if os.path.realpath(store.root) != os.path.realpath(store_root(config.calibration.directory, args.workdir)):
        return None
    try:
        return open_audit_log(config, args.workdir)
    except (StoreError, OSError) as err:
        return (f"a new version of the cell's calibration set is recorded in its audit log, which cannot be written: "
                f"{err}; run as a user who may write it, or compute into a folder of your own with --store DIR")


def _audit_store(
    procedure: str, audit: CellStore | None, saved: CalibrationSet, outcome: Outcome, store: CalibrationStore,
    args: argparse.Namespace,
) -> int:
    """Append ``calibration.store`` for ``saved`` to ``audit`` and close it; 1 when it could not be written."""
    import sqlite3

    from cellctl.calibration.provenance import STORE_ACTION, store_params
    from cellctl.store import StoreError

    who = saved.written_by
    assert who is not None
    if audit is None:
        print(f"  not in an audit log: {store.root} is not the calibration.directory of --workdir {args.workdir}")
        return 0
    try:
        audit.append_audit(actor=who.actor, source=who.source, action=STORE_ACTION, params=store_params(saved, outcome, store.root))
    except (StoreError, sqlite3.Error) as err:
        print(f"{procedure}: version {saved.version} is stored, but the cell's audit log ([store] path under --workdir "
              f"{args.workdir}) could not be written ({err}); the service records the change when it adopts the version",
              file=sys.stderr)  # fmt: skip
        return 1
    finally:
        audit.close()
    print(f"  audit log: {STORE_ACTION} by {who.actor} ({who.source})")
    return 0


def job_command(procedure: str) -> Callable[[argparse.Namespace], int]:
    def command(args: argparse.Namespace) -> int:
        from cellctl.commissioning.terminal import follow, print_plan

        if args.dataset:
            if args.dry_run or args.list_poses:
                print(f"{'--dry-run' if args.dry_run else '--list-poses'} plans a job on the cell; --dataset computes "
                      "offline (and stores the result): give one of them", file=sys.stderr)
                return 2
            return _offline(args, procedure)
        client = _client(args)
        options = _options(args, procedure)
        if args.dry_run or args.list_poses:  # --list-poses is a dry run: it lists, nothing moves
            print_plan(client.plan_job(procedure, options, poses=args.list_poses), sys.stdout)
            return 0
        job = client.start_job(procedure, options)
        return follow(client, job)

    return command


def _part_problems(problems: list[str]) -> dict[str, list[str]]:
    """check_ready's lines by the part they are about (each starts with ``"<part>: "`` or ``"<part> of recipe NAME: "``)."""
    by_part: dict[str, list[str]] = {name: [] for name in PART_NAMES}
    for line in problems:
        head, _, rest = line.partition(": ")
        by_part.get(head.split(" of recipe ")[0], []).append(rest)
    return by_part


def cmd_status(args: argparse.Namespace) -> int:
    store = _store(args)
    try:
        cal = store.current()
        history = store.history()
    except CalibrationSetError as err:
        print(f"the calibration store is damaged:\n{err}", file=sys.stderr)
        return 2
    root = store.root.resolve()
    config = load_config(args.config) if getattr(args, "config", None) else None
    first = None if config is None else config.default_recipe
    problems = check_ready(cal, datetime.now(timezone.utc), first_recipe=first, config=config, store_root=store.root)
    if cal is None:
        print(f"no calibration set in {root}")
        if not args.store:
            print(f"  (calibration.directory under --workdir {args.workdir}; give the --workdir `cellctl serve` runs with, "
                  f"or set ${WORKDIR_ENV})")  # fmt: skip
    else:
        print(f"calibration store {root}: set version {cal.version} in use, {len(history)} version(s) kept")
        by_part = _part_problems(problems)
        slot = None if first is None else parts_of(cal, None, first)  # where the first recipe's own parts are read
        for name in PART_NAMES:
            p = cal.part(name, slot)
            if p is None:
                print(f"  {name:10s} missing")
                continue
            verdict = "ok" if p.status == "ok" and not by_part[name] else "FAILED" if p.status == "failed" else "NEEDS WORK"
            print(f"  {name:10s} {verdict:10s} {p.calibrated_utc:%Y-%m-%d %H:%M} UTC  {p.id}" + (f"  ({p.failure})" if p.failure else ""))
    if args.history:
        for row in history:
            print(f"  v{row['version']:<4d} {row['created_utc']}  {row['note']}")
    print("ready for production" if not problems else "not ready:\n  - " + "\n  - ".join(problems))
    recipes = config.process.recipes if config is not None and cal is not None else ()
    for recipe in recipes[1:]:
        own = check_ready(cal, datetime.now(timezone.utc), recipe=recipe.name, first_recipe=recipes[0].name, config=config,
                          store_root=store.root)
        print(f"recipe {recipe.name}: " + ("ready" if not own else "not ready: " + "; ".join(own)))
    return 0 if not problems else 1
