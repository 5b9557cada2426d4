"""A calibration set built part by part in a test: valid values of each part (the set's readiness checks their shape
and links, not their accuracy) and a commit of named parts at a chosen date with a chosen validity."""

from __future__ import annotations

from datetime import datetime
from typing import Any

import numpy as np

from cellctl.calibration.calibration_set import DEPENDS_ON, CalibrationStore, make_part

CELL_PARTS = ("camera", "hand_eye", "laser", "teaching", "pixel_map")
RECIPE_PARTS = ("teaching", "pixel_map")
POSE = np.eye(4).tolist()
VALUES: dict[str, dict[str, Any]] = {
    "camera": {"K": [[5249.6, 0.0, 1014.7], [0.0, 5248.6, 1012.0], [0.0, 0.0, 1.0]], "dist": [-0.158, -0.025, -3e-4, 4e-4, 0.04],
               "image_size": [2048, 2048]},
    "hand_eye": {"T_H_C": POSE},
    "laser": {"r": [43.68, -40.49, 90.10], "l": (np.array([0.9977, 0.0626, 0.0265]) / np.linalg.norm([0.9977, 0.0626, 0.0265])).tolist()},
    "teaching": {"T0": POSE, "C_Pos_0": POSE, "g_Pos_0": POSE, "u_d": 1014.0, "v_d": 1012.0, "theta_d": 0.0, "top_angle_d": 0.0,
                 "right_angle_d": 0.0},
    "pixel_map": {"affine": [[0.0762, 0.0, -77.3], [0.0, 0.0762, -77.1]], "scale_mm_per_px": 0.0762},
}  # fmt: skip


def commit(store: CalibrationStore, names: tuple[str, ...], recipe: str | None, when: datetime, valid_days: float = 90.0) -> None:
    """Calibrate ``names`` at ``when`` (recorded valid ``valid_days``), in ``recipe``'s own place (None: the cell's)."""
    for name in names:
        cur = store.current()
        inputs = {dep: cur.part(dep, recipe).id for dep in DEPENDS_ON[name]} if cur else {}  # type: ignore[union-attr]
        values = dict(VALUES[name], recipe=recipe or "side-window") if name == "teaching" else VALUES[name]
        part = make_part(name, values=values, method="test", when=when, valid_days=valid_days, inputs=inputs)
        store.commit(name, part, now=when, recipe=recipe)
