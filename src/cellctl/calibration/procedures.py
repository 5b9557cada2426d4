"""The calibration procedures, one per part of the set: what to collect, what to compute, in order.

The CLI (``cellctl calibrate ...``/``cellctl teach``) runs one procedure; the simulated cell's
self-calibration (:mod:`cellctl.calibration.source`) runs the ones that are missing, in
:data:`ORDER`. Collecting drives the twin through the ports; computing works on the saved dataset.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cellctl.calibration.calibration_set import CalibrationSet
from cellctl.calibration.collect import Progress
from cellctl.calibration.compute import (
    Outcome,
    compute_camera,
    compute_hand_eye,
    compute_laser,
    compute_nine_point,
    compute_teaching,
    detect_views,
)
from cellctl.calibration.dataset import Dataset
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.runs import collect_board_views, collect_laser_plane, collect_nine_point, collect_teaching
from cellctl.config.schema import CellConfig

Collect = Callable[..., Awaitable[Dataset]]
Compute = Callable[[Dataset, "CalibrationSet | None", CellConfig], Outcome]


def check_inputs(cal: CalibrationSet | None, part: str, names: tuple[str, ...]) -> None:
    """Refuse ``part`` naming the first of ``names`` that is missing or failed in the set."""
    for n in names:
        p = None if cal is None else cal.part(n)
        if p is None or p.status != "ok":
            raise CalibrationRefused(part, "missing_input", f"{n} must be calibrated first")


def need_parts(cal: CalibrationSet | None, part: str, *names: str) -> CalibrationSet:
    """The set, if it has every named part (at least one) ok; else refuse ``part``."""
    check_inputs(cal, part, names)
    assert cal is not None and names
    return cal


@dataclass(frozen=True)
class Procedure:
    """One part's calibration: the dataset kind it collects, how, and how it is computed."""

    part: str
    kind: str
    method: str
    needs: tuple[str, ...]
    collect: Collect  # (twin, config, cal, dest, progress=..., **options)
    compute: Compute


async def _board(twin: Any, config: CellConfig, cal: CalibrationSet | None, dest: Path, *, progress: Progress, views: int | None = None) -> Dataset:
    return await collect_board_views(twin, config, dest, n_views=views, progress=progress)


async def _laser(twin: Any, config: CellConfig, cal: CalibrationSet | None, dest: Path, *, progress: Progress, poses: int | None = None) -> Dataset:
    return await collect_laser_plane(twin, config, dest, n_poses=poses, progress=progress)


async def _teach(twin: Any, config: CellConfig, cal: CalibrationSet | None, dest: Path, *, progress: Progress) -> Dataset:
    return await collect_teaching(twin, config, need_parts(cal, "teaching", "camera", "hand_eye", "laser"), dest, progress=progress)


async def _nine(twin: Any, config: CellConfig, cal: CalibrationSet | None, dest: Path, *, progress: Progress) -> Dataset:
    return await collect_nine_point(twin, config, need_parts(cal, "pixel_map", "camera", "teaching"), dest, progress=progress)


def _hand_eye(ds: Dataset, cal: CalibrationSet | None, cfg: CellConfig) -> Outcome:
    return compute_hand_eye(ds, cal, cfg, detect_views(ds, cfg.calibration.procedure.camera.refine))


PROCEDURES: dict[str, Procedure] = {
    "camera": Procedure("camera", "board_views", "zhang", (), _board, lambda ds, cal, cfg: compute_camera(ds, cfg)),
    "hand_eye": Procedure("hand_eye", "board_views", "tsai", ("camera",), _board, _hand_eye),
    "laser": Procedure("laser", "laser_plane", "plane constraint", (), _laser, lambda ds, cal, cfg: compute_laser(ds, cfg)),
    "teaching": Procedure("teaching", "teaching", "teaching", ("camera", "hand_eye", "laser"), _teach, compute_teaching),
    "pixel_map": Procedure("pixel_map", "nine_point", "nine-point", ("camera", "teaching"), _nine, compute_nine_point),
}
# The order a cell is commissioned in: each part only needs parts before it.
ORDER = ("camera", "hand_eye", "laser", "teaching", "pixel_map")
