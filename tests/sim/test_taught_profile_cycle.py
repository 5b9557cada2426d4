"""The cycle's shot checked against the profile the stored teaching recorded, against the twin's truth.

A calibration set is built from the twin's true camera, hand-eye and laser, and a teaching part
whose template and profiles come from a twin frame of the usual car body at the shooting pose;
it is stored as JSON and read back, and the cycle's calibration is taken from it as production
takes it. A cycle shot (CycleRun's own measuring step, its camera handing over twin frames) of a
body with a dark paint line 2.8 mm outside the wall's edge is then refused; without the recorded
profile it gives an offset 2.8 mm off on both axes.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cellctl.calibration.calibration_set import CalibrationSet, make_part
from cellctl.calibration.set_parts import Parts
from cellctl.calibration.source import cycle_calibration_from_set
from cellctl.calibration.taught_shot import taught_profile
from cellctl.cell.cycle import CycleRun
from cellctl.cell.cycle_values import CellDevices, CycleCalibration
from cellctl.config import load_config
from cellctl.config.feature import shot_feature
from cellctl.config.surface import BandConfig, SurfaceConfig
from cellctl.geometry.pose import make_pose
from cellctl.geometry.rotation import rot_z
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.image_truth import camera_pose_seeing_corner
from cellctl.sim.world import nominal_world
from cellctl.vision import Lens, Refusal
from cellctl.vision.feature import FeatureShot, detect_feature

ROOT = Path(__file__).resolve().parents[2]
NOW = datetime(2025, 3, 1, tzinfo=timezone.utc)
PAINT_LINE = SurfaceConfig(paint_band=BandConfig(width_mm=(2.8, 2.8), dn=(85.0, 85.0)))
TEMPLATE_PX = (990.0, 1040.0)


def _config():  # type: ignore[no-untyped-def]
    config = load_config(ROOT / "config" / "sim.toml")
    return config.for_recipe(config.default_recipe)


def _frame(config: Any, surface: SurfaceConfig, seed: int) -> np.ndarray:
    """A twin frame of the nominal car body with ``surface``, the corner at the template's place."""
    sim = config.sim
    renderer = CameraRenderer(sim.camera.intrinsics, sim.camera.render.model_copy(update={"surface": surface}))
    world = nominal_world(sim.world)
    pose = camera_pose_seeing_corner(renderer.camera, world, TEMPLATE_PX, R_T_C=rot_z(np.radians(0.4)))
    return renderer.render(pose, world, rng=np.random.default_rng(seed)).image


def _stored_set(config: Any) -> CalibrationSet:
    """The twin's true sensors and a teaching of its template frame, written as a set file is and read back."""
    sim, feature = config.sim, shot_feature(config)
    lens = Lens.from_intrinsics(sim.camera.intrinsics)
    template = detect_feature(_frame(config, SurfaceConfig(), 1), lens, config.vision, None, corner_radius=feature.corner_radius)
    assert template.ok and template.features is not None, template.message
    f, i = template.features, sim.camera.intrinsics
    pose = make_pose(np.eye(3), [1500.0, -900.0, 1700.0]).tolist()  # T0 and the poses: not used by the shot
    values = {
        "camera": {"K": i.camera_matrix().tolist(), "dist": [i.k1, i.k2, i.p1, i.p2, i.k3], "image_size": [i.width_px, i.height_px]},
        "hand_eye": {"T_H_C": sim.camera.hand_eye.T_H_C().tolist()},
        "laser": {"r": list(sim.laser.r), "l": list(sim.laser.l)},
        "pixel_map": {"affine": [[0.0762, 0.0, -77.3], [0.0, 0.0762, -77.1]], "scale_mm_per_px": 0.0762},
        "teaching": {
            "T0": pose, "C_Pos_0": pose, "g_Pos_0": pose, "u_d": f.u_px, "v_d": f.v_px, "theta_d": f.theta_rad,
            "top_angle_d": f.top_angle_rad, "right_angle_d": f.right_angle_rad,
            "profile": taught_profile(template.measurement, config.vision.feature),  # as compute_teaching records it
        },
    }  # fmt: skip
    parts = {name: make_part(name, values=v, method="twin truth", when=NOW, valid_days=30.0) for name, v in values.items()}
    stored = CalibrationSet(version=1, created_utc=NOW, parts=Parts(**parts)).model_dump_json()  # type: ignore[arg-type]
    return CalibrationSet.model_validate_json(stored)


@dataclass
class _Frame:
    image: np.ndarray


class _Camera:
    def __init__(self, image: np.ndarray) -> None:
        self.image = image

    async def grab(self, timeout_s: float) -> _Frame:
        return _Frame(self.image)


class _Recorder:
    def __init__(self) -> None:
        self.images: list[str] = []

    async def step_started(self, step: Any) -> None: ...

    async def step_figures(self, step: Any, figures: dict[str, Any]) -> None: ...

    async def install_started(self, target: Any) -> None: ...

    async def image(self, name: str, png: bytes) -> None:
        self.images.append(name)


def _cycle_shot(config: Any, cal: CycleCalibration, image: np.ndarray) -> tuple[FeatureShot, Any, list[str]]:
    """CycleRun's measuring step on ``image``: the shot, its offset (None: refused) and the images it recorded."""
    rec = _Recorder()
    devices = CellDevices(laser=None, camera=_Camera(image), robot=None)  # type: ignore[arg-type]
    run = CycleRun(devices, cal, config.process, config.vision, rec, feature=shot_feature(config))
    shot, offset = asyncio.run(run._measure(1))
    return shot, offset, rec.images


@pytest.fixture(scope="module")
def stored() -> tuple[Any, CycleCalibration]:
    config = _config()
    cal = cycle_calibration_from_set(_stored_set(config), config.process.align.laser_range_mm)
    return config, cal


def test_the_stored_teaching_hands_its_profile_to_the_cycle_which_refuses_a_paint_line(stored) -> None:  # type: ignore[no-untyped-def]
    config, cal = stored
    assert cal.taught_profile is not None and set(cal.taught_profile.edges) == {"top", "right"}
    image = _frame(config, PAINT_LINE, 2)
    # Without the record (a set taught before profiles were recorded): an offset 2.8 mm off on both
    # axes goes on to the install. The frame shows the corner exactly where it was taught.
    plain, offset, _ = _cycle_shot(config, replace(cal, taught_profile=None), image)
    assert plain.ok and offset is not None
    assert 2.5 < abs(offset.dx_mm) < 3.1 and 2.5 < abs(offset.dy_mm) < 3.1, offset
    shot, offset, images = _cycle_shot(config, cal, image)
    assert offset is None and shot.refusal is Refusal.FEATURE_NOT_FOUND
    assert "differs from the one taught" in shot.message and images == ["shot1"]  # the refusal's picture is kept


def test_an_unchanged_body_gives_the_cycle_the_same_offset(stored) -> None:  # type: ignore[no-untyped-def]
    config, cal = stored
    image = _frame(config, SurfaceConfig(), 3)
    _, plain, _ = _cycle_shot(config, replace(cal, taught_profile=None), image)
    shot, offset, _ = _cycle_shot(config, cal, image)
    assert shot.ok and offset is not None and offset == plain
    assert abs(offset.dx_mm) < 0.02 and abs(offset.dy_mm) < 0.02, offset
