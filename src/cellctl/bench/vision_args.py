"""The options of the vision benchmark, apart from it so that ``cellctl``'s parser stays light to import."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``python -m cellctl.bench.vision`` and ``cellctl bench vision`` take the same options."""
    parser.add_argument("--runs", type=int, default=30, help="timed detections of one frame (default 30)")
    parser.add_argument("--renders", type=int, default=200, help="renders of the clean opening (default 200)")
    parser.add_argument("--surface-renders", type=int, default=200, help="renders per surface case (default 200)")
    parser.add_argument("--disturbed-renders", type=int, default=100, help="renders per disturbance (default 100)")
    parser.add_argument("--only", default="", help="run only the cases whose name contains this text")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--json", default=None, help="write the figures to this JSON file")
