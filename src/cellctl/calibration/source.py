"""The cycle's calibration from the versioned calibration set (the cell's CalibrationSource).

The set is read from its folder before every cycle (a new version is picked up at once), checked
for completeness, validity and age (:func:`check_ready`), and turned into what a cycle needs.
The set changes only through commissioning jobs (:mod:`cellctl.commissioning`) or
``cellctl calibrate ... --dataset``.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.calibration.calibration_set import PART_NAMES, CalibrationSet, CalibrationStore, check_ready, store_root
from cellctl.calibration.errors import CalibrationRefused
from cellctl.cell.cycle import CycleCalibration
from cellctl.config.schema import CellConfig
from cellctl.vision import AffineMap, CornerFeatures, Lens

def cycle_calibration_from_set(cal: CalibrationSet, laser_range_mm: tuple[float, float]) -> CycleCalibration:
    """The parts a cycle needs, from a set that :func:`check_ready` accepts."""
    K, D = cal.camera_matrix(), cal.dist_coeffs()
    w, h = cal.image_size()
    k1, k2, p1, p2, k3 = (float(v) for v in D[:5])
    lens = Lens(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), k1, k2, p1, p2, k3, int(w), int(h))
    r, l = cal.laser_ray()  # noqa: E741
    q = cal.parts.pixel_map.quality if cal.parts.pixel_map is not None else {}
    residuals = np.asarray(q.get("map_residuals_mm", []), dtype=float)
    nine_point = AffineMap(cal.pixel_affine(), residuals, float(q.get("map_rms_mm", 0.0)), float(q.get("map_max_mm", 0.0)))
    t = cal.template()
    template = CornerFeatures(t["u_d"], t["v_d"], t["theta_d"], t["top_angle_d"], t["right_angle_d"])
    return CycleCalibration(
        lens=lens,
        T_H_C=cal.T_H_C(),
        laser_r=r,
        laser_l=l,
        laser_range_mm=laser_range_mm,
        nine_point=nine_point,
        taught=cal.taught(),
        template=template,
    )


class CalibrationSetSource:
    """A CalibrationSource over a calibration store folder."""

    def __init__(self, store: CalibrationStore, config: CellConfig) -> None:
        self.store = store
        self.config = config
        self._cached: tuple[int, CycleCalibration] | None = None

    @classmethod
    def from_config(cls, config: CellConfig, *, workdir: Path) -> "CalibrationSetSource":
        return cls(CalibrationStore(store_root(config.calibration.directory, workdir)), config)

    def _current(self) -> CalibrationSet | None:
        return self.store.current()

    def problems(self) -> list[str]:
        return check_ready(self._current(), datetime.now(timezone.utc))

    def cycle_calibration(self) -> CycleCalibration:
        cal = self._current()
        if cal is None:
            raise CalibrationRefused("set", "missing_input", "there is no calibration set; calibrate the cell first")
        if self._cached is None or self._cached[0] != cal.version:
            self._cached = (cal.version, cycle_calibration_from_set(cal, self.config.process.align.laser_range_mm))
        return self._cached[1]

    def summary(self) -> dict[str, Any]:
        cal = self._current()
        if cal is None:
            return {"source": str(self.store.root), "version": None, "parts": {}}
        parts = {}
        for name in PART_NAMES:
            p = cal.part(name)
            parts[name] = None if p is None else {
                "status": p.status, "calibrated_utc": p.calibrated_utc.isoformat(), "method": p.method,
                "quality": p.quality, "failure": p.failure,
            }  # fmt: skip
        return {"source": str(self.store.root), "version": cal.version, "parts": parts}

    def history(self) -> list[dict[str, Any]]:
        return self.store.history()
