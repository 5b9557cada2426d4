"""Recording a computed calibration as a new version of the calibration set."""

from __future__ import annotations

import platform
from datetime import datetime

import cv2
import numpy as np
import scipy

import cellctl
from cellctl.calibration.calibration_set import PART_NAMES, CalibrationSet, CalibrationStore, make_part
from cellctl.calibration.compute import Outcome
from cellctl.calibration.dataset import Dataset
from cellctl.calibration.set_parts import WrittenBy
from cellctl.config.schema import CellConfig


def software() -> dict[str, str]:
    """The versions a result was computed with."""
    return {
        "cellctl": getattr(cellctl, "__version__", "unknown"),
        "opencv": cv2.__version__,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "python": platform.python_version(),
    }


def validity_days(config: CellConfig, part: str) -> float:
    """How long a new part stays valid: the configuration's ``calibration.max_age_days``."""
    if part not in PART_NAMES:
        raise KeyError(f"unknown calibration part {part!r}")
    return float(config.calibration.max_age_days)


def record(
    store: CalibrationStore, outcome: Outcome, ds: Dataset | None, config: CellConfig, when: datetime, note: str = "",
    measured: datetime | None = None, written_by: WrittenBy | None = None,
) -> CalibrationSet:
    """Store a calibration that passed its gates as a new version of the set, at ``when``.

    The part counts as calibrated at ``measured`` (the dataset's capture, for a recompute of older data) or else at
    ``when``: its validity runs from the measurement, not from the computing. ``written_by``: who wrote it outside the
    service (the offline CLI), kept in the set file.
    """
    part = make_part(
        outcome.part,
        values=outcome.values,
        method=outcome.method,
        when=measured or when,
        valid_days=validity_days(config, outcome.part),
        quality=outcome.quality,
        warnings=outcome.warnings,
        inputs=outcome.inputs,
        dataset=None if ds is None else ds.ref({"kind": ds.kind}, store_root=store.root),  # datasets/<name>: moves with the store
        software=software(),
    )
    return store.commit(outcome.part, part, note=note or f"{outcome.part} calibrated", now=when, recipe=outcome.recipe,
                        written_by=written_by)
