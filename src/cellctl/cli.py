"""``cellctl``: the command line of the cell controller."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from cellctl.calibration import cli as calibration_cli
from cellctl.config import ConfigError, load_config

DEFAULT_CONFIG = Path(__file__).resolve().parents[2] / "config" / "sim.toml"


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
        print(f"run {k + 1}:")
        print(f"  spots used {len(res.wall.inliers)}/{len(res.points_B)}, rejected {[s.index for s in res.wall.rejected]}")
        print(f"  wall normal (B)         {np.array2string(res.wall.normal, precision=6)}")
        print(f"  fit RMS / max residual  {res.wall.plane.rms:.4f} / {res.wall.plane.max_residual:.4f} mm")
        if unc is not None:
            print(f"  predicted normal error  {np.degrees(unc.rms_rad):.4f} deg rms ({unc.sigma_source})")
        print(f"  flange turn             {np.degrees(res.rotation_rad):.3f} deg, LM vs closed form {res.axis_agreement_rad:.1e} rad")
        print(f"  distance correction     {res.distance.delta_d_mm:+.3f} mm (eq. 14)")
        print(f"  true camera axis error  {np.degrees(run.camera_axis_error_rad):.4f} deg")
        print(f"  true distance error     {run.distance_error_mm:+.4f} mm")
    print(f"camera axis error vs truth: median {np.median(errors):.4f} deg, max {np.max(errors):.4f} deg")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``cellctl``."""
    parser = argparse.ArgumentParser(prog="cellctl", description="Cell controller for robotic glass installation.")
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help="TOML configuration (default: %(default)s)")
    sub = parser.add_subparsers(dest="command", required=True)
    p_align = sub.add_parser("align", help="run the laser alignment on the simulated cell and score it")
    p_align.add_argument("--seed", type=int, default=1)
    p_align.add_argument("--runs", type=int, default=3)
    p_align.set_defaults(func=_cmd_align)
    calibration_cli.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``cellctl`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except ConfigError as err:
        print(f"configuration refused:\n{err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
