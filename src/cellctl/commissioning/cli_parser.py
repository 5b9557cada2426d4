"""The parser of ``cellctl calibrate ...`` and ``cellctl teach``: options and help, without the commands' imports.

Each command's function is imported from :mod:`cellctl.commissioning.cli` when it runs, so that every other ``cellctl``
command (``status``, ``parts export``, ``--help``) starts without loading the calibration code it does not use.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from cellctl.cli_args import WORKDIR_ENV, add_remote_options, default_workdir
from cellctl.config.calibration_procedure import HAND_EYE_METHODS

JOB_HELP = (
    "Runs as a job of the running service (cellctl serve): a progress bar, each prompt answered at the keyboard "
    "(Enter confirms, c cancels), Ctrl-C cancels and stops the robot. --dataset computes offline instead. "
    "Exit status: 0 done, 1 refused, failed or cancelled, 2 usage or configuration problem, 130 Ctrl-C."
)

# CLI word -> procedure
COMMAND_PROCEDURES = {"camera": "camera", "hand-eye": "hand_eye", "laser": "laser", "nine-point": "pixel_map", "verify": "verify"}


def _job(procedure: str) -> Callable[[argparse.Namespace], int]:
    """The command that runs ``procedure`` as a job (or offline from a dataset)."""

    def command(args: argparse.Namespace) -> int:
        from cellctl.commissioning.cli import job_command

        return job_command(procedure)(args)

    return command


def _status(args: argparse.Namespace) -> int:
    from cellctl.commissioning.cli import cmd_status

    return cmd_status(args)


def _store_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--store", help="calibration store folder (default: calibration.directory of the configuration)")
    p.add_argument(
        "--workdir", type=Path, default=default_workdir(),
        help="the folder a relative calibration.directory is taken from, as `cellctl serve --workdir` "
             f"(default: ${WORKDIR_ENV}, else the current folder)",
    )  # fmt: skip


def _common(p: argparse.ArgumentParser) -> None:
    add_remote_options(p)
    p.add_argument("--dry-run", action="store_true", help="print the plan (poses, reach, rotation spread, robot time); move nothing")
    p.add_argument("--list-poses", action="store_true", help="print the plan with every planned pose; implies --dry-run (nothing moves)")
    p.add_argument("--no-store", action="store_true", help="compute and print only; the calibration set is not changed")
    p.add_argument("--dataset", help="compute offline, in this process, from this saved dataset folder")
    p.add_argument("--accept-cell", default=None, metavar="CELL_ID",
                   help="with --dataset: take a dataset recorded on cell CELL_ID (this cell under a former cell_id)")
    _store_options(p)
    p.set_defaults(method_override=None, views=None, poses=None)


def _job_parser(
    parent: argparse._SubParsersAction, word: str, help_text: str, procedure: str | None = None  # type: ignore[type-arg]
) -> argparse.ArgumentParser:
    """The sub-command ``word`` that runs ``procedure`` (by default the one COMMAND_PROCEDURES names) as a job."""
    p: argparse.ArgumentParser = parent.add_parser(word, help=help_text, description=f"{help_text[0].upper()}{help_text[1:]}. {JOB_HELP}")
    _common(p)
    p.set_defaults(func=_job(procedure or COMMAND_PROCEDURES[word]))
    return p


def _count_option(p: argparse.ArgumentParser, positive: Callable[[str], int], what: str, setting: str) -> None:
    """``--views`` or ``--poses``: how many to collect, by default the configuration's ``setting``."""
    p.add_argument(f"--{what}", type=positive, default=None, help=f"number of {what} (default: {setting})")


def _recipe_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--recipe", default=None, help="the recipe taught (a name of [[process.recipes]]; default: the first)")


def register(subparsers: argparse._SubParsersAction, positive: Callable[[str], int]) -> None:  # type: ignore[type-arg]
    """Add ``calibrate`` and ``teach`` to cellctl's parser; ``positive`` parses a whole number >= 1."""
    cal = subparsers.add_parser("calibrate", help="calibrate the camera, hand-eye, laser or pixel map on the running cell")
    sub = cal.add_subparsers(dest="part", required=True)

    p = _job_parser(sub, "camera", "camera intrinsics by Zhang's method from checkerboard views")
    _count_option(p, positive, "views", "calibration.procedure.camera.n_views")

    p = _job_parser(sub, "hand-eye", "hand-eye T_H_C (Tsai; Park, Horaud, Andreff, Daniilidis compared)")
    _count_option(p, positive, "views", "calibration.procedure.camera.n_views")
    p.add_argument("--method", dest="method_override", choices=HAND_EYE_METHODS, default=None, help="the method whose result is stored")

    p = _job_parser(sub, "laser", "laser origin r and direction l from a plane seen from many poses")
    _count_option(p, positive, "poses", "calibration.procedure.laser.n_poses")

    p = _job_parser(sub, "nine-point", "pixel scale (eq. 15) and the nine-point pixel-to-workpiece map")
    _recipe_option(p)
    _job_parser(sub, "verify", "a few minutes' check of how far hand-eye and laser have drifted since they were calibrated")

    p = sub.add_parser("status", help="the current calibration set, its history and whether production may start")
    _store_options(p)
    p.add_argument("--history", action="store_true", help="list every version")
    p.set_defaults(func=_status)

    p = _job_parser(
        subparsers, "teach", "teach T0, C_Pos_0, the corner template and g_Pos_0 (paper 4.3 step 1) on the running cell",
        procedure="teaching",
    )  # fmt: skip
    _recipe_option(p)
