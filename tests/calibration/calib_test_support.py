"""Shared data for the calibration tests: the twin's board views, collected once per test process.

Rendering is the expensive part (a 2048 x 2048 frame per view), so one seeded collection of ten
views serves the camera and the hand-eye tests; every test asserts against the twin's truth.
"""

from __future__ import annotations

import asyncio
import functools
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from shared_support import scratch_dir

from cellctl.calibration.board import BoardDetection
from cellctl.calibration.calibration_set import CalibrationStore, make_part
from cellctl.calibration.compute import Outcome, compute_camera, detect_views
from cellctl.calibration.dataset import Dataset
from cellctl.calibration.recording import record
from cellctl.cli import DEFAULT_CONFIG
from cellctl.config import load_config
from cellctl.config.schema import CellConfig
from cellctl.sim.commissioning import TwinCommissioning

SEED = 11
N_VIEWS = 10
NOW = datetime(2026, 1, 15, 12, 0, tzinfo=timezone.utc)


@functools.lru_cache(maxsize=1)
def config() -> CellConfig:
    return load_config(DEFAULT_CONFIG)


def with_robot(cfg: CellConfig, **robot: float) -> CellConfig:
    """The configuration with some of the twin robot's error sources changed."""
    return cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"robot": cfg.sim.robot.model_copy(update=robot)})})


def scratch(name: str) -> Path:
    return scratch_dir(f"calib-{name}")


@functools.lru_cache(maxsize=1)
def board_views() -> tuple[Dataset, list[tuple[str, BoardDetection]]]:
    """Ten views of the board on the wall of the seeded twin, and the board found in each."""

    async def go() -> Dataset:
        twin = TwinCommissioning(config(), seed=SEED)
        try:
            return await twin.collect("camera", None, scratch("views") / "ds", views=N_VIEWS)
        finally:
            await twin.close()

    ds = asyncio.run(go())
    return ds, detect_views(ds)


@functools.lru_cache(maxsize=1)
def camera_outcome() -> Outcome:
    ds, dets = board_views()
    return compute_camera(ds, config(), dets)


def store_with_camera() -> CalibrationStore:
    """A fresh store holding the camera calibrated from the shared views."""
    ds, _ = board_views()
    store = CalibrationStore(scratch("store"))
    record(store, camera_outcome(), ds, config(), NOW)
    return store


# Valid values of every part of a calibration set (for the set's own tests).
POSE = np.eye(4).tolist()
VALUES = {
    "camera": {"K": [[5249.6, 0.0, 1014.7], [0.0, 5248.6, 1012.0], [0.0, 0.0, 1.0]], "dist": [-0.158, -0.025, -3e-4, 4e-4, 0.04], "image_size": [2048, 2048]},
    "hand_eye": {"T_H_C": POSE},
    "laser": {"r": [43.68, -40.49, 90.10], "l": (np.array([0.9977, 0.0626, 0.0265]) / np.linalg.norm([0.9977, 0.0626, 0.0265])).tolist()},
    "teaching": {"T0": POSE, "C_Pos_0": POSE, "g_Pos_0": POSE, "u_d": 1014.0, "v_d": 1012.0, "theta_d": 0.0, "top_angle_d": 0.0, "right_angle_d": 0.0},
    "pixel_map": {"affine": [[0.0762, 0.0, -77.3], [0.0, 0.0762, -77.1]], "scale_mm_per_px": 0.0762},
}
INPUTS = {"camera": [], "hand_eye": ["camera"], "laser": [], "teaching": ["camera", "hand_eye", "laser"], "pixel_map": ["camera", "teaching"]}


def store_with_common_parts(root: Path, when: datetime = NOW) -> CalibrationStore:
    """A store holding camera, hand_eye and laser (the test values, calibrated ``when``, valid 90 days)."""
    store = CalibrationStore(root)
    for name in ("camera", "hand_eye", "laser"):
        cur = store.current()
        inputs = {dep: cur.part(dep).id for dep in INPUTS[name]} if cur else {}  # type: ignore[union-attr]
        store.commit(name, make_part(name, values=VALUES[name], method="test", when=when, valid_days=90.0, inputs=inputs),
                     now=when)  # fmt: skip
    return store


def commit_teaching(store: CalibrationStore, slot: str | None, taught_for: str | None, shift_mm: float, *,
                    when: datetime = NOW, nine_point: bool = True) -> None:
    """A teaching recording ``taught_for`` (T0 and C_Pos_0 moved ``shift_mm`` in y) and its nine-point map, at ``slot``."""
    cal = store.current()
    assert cal is not None
    moved = {}
    for pose in ("T0", "C_Pos_0"):
        T = np.array(VALUES["teaching"][pose], dtype=float)
        T[1, 3] += shift_mm
        moved[pose] = T.tolist()
    values = dict(VALUES["teaching"], **moved, recipe=taught_for)
    inputs = {dep: cal.part(dep).id for dep in INPUTS["teaching"]}  # type: ignore[union-attr]
    store.commit("teaching", make_part("teaching", values=values, method="test", when=when, valid_days=90.0, inputs=inputs),
                 now=when, recipe=slot)  # fmt: skip
    if nine_point:
        inputs = {"camera": cal.part("camera").id, "teaching": store.current().part("teaching", slot).id}  # type: ignore[union-attr]
        store.commit("pixel_map", make_part("pixel_map", values=VALUES["pixel_map"], method="test", when=when, valid_days=90.0,
                                            inputs=inputs), now=when, recipe=slot)  # fmt: skip
