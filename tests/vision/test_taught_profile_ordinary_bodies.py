"""The taught-profile check passes ordinary car bodies of the twin (sim.toml's own surface ranges).

Teaching records the template profile of one twin car body (surface seed 1); other car bodies the twin
draws within the same [sim.camera.render.surface] ranges are shot with the corner exactly at the same
pixel (the twin's truth: the camera pose is solved so the true corner projects to TEMPLATE_PX). The rule
alone finds each corner within a pixel of the truth, and so must the check. These bodies' flange-to-seal
step (a band whose width the twin varies 4-7 mm, 52-91 px) is as large as the rule counts and lies
elsewhere than on the teaching body; it lies beyond the feature, where it changes no count, so it is not
compared (it refused them feature_not_found, 2 of 30 cycles of `cellctl bench accuracy --calibration data
--seed 2 --trials 30`; about 1.2 % of the twin's bodies).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from cellctl.calibration.set_parts import TaughtProfileValues
from cellctl.calibration.taught_shot import taught_profile, taught_profile_of
from cellctl.config import load_config
from cellctl.config.feature import shot_feature
from cellctl.geometry.rotation import rot_z
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.image_truth import camera_pose_seeing_corner
from cellctl.sim.world import nominal_world
from cellctl.vision import Lens
from cellctl.vision.feature import detect_feature

TEMPLATE_PX = (990.0, 1040.0)  # where the twin puts the true corner (raw px)
_config = load_config(Path(__file__).resolve().parents[2] / "config" / "sim.toml")
CONFIG = _config.for_recipe(_config.default_recipe)
RENDERER = CameraRenderer(CONFIG.sim.camera.intrinsics, CONFIG.sim.camera.render)  # sim.toml's surface, unchanged
LENS = Lens.from_intrinsics(CONFIG.sim.camera.intrinsics)
RADIUS = shot_feature(CONFIG).corner_radius


def _shot(surface_seed: int, noise_seed: int, taught=None):  # type: ignore[no-untyped-def]
    world = dataclasses.replace(nominal_world(CONFIG.sim.world), surface_seed=surface_seed)
    pose = camera_pose_seeing_corner(RENDERER.camera, world, TEMPLATE_PX, R_T_C=rot_z(np.radians(0.4)))
    image = RENDERER.render(pose, world, rng=np.random.default_rng(noise_seed)).image
    return detect_feature(image, LENS, CONFIG.vision, None, corner_radius=RADIUS, taught=taught)


@pytest.fixture(scope="module")
def taught():  # type: ignore[no-untyped-def]
    template = _shot(1, 1)
    assert template.ok, template.message
    values = taught_profile(template.measurement, CONFIG.vision.feature)  # as compute_teaching records it
    return taught_profile_of(TaughtProfileValues.model_validate(values))  # as the stored set hands it to the cycle


@pytest.mark.parametrize("body", [1454, 1670, 2257])
def test_an_ordinary_twin_body_is_not_refused(taught, body: int) -> None:  # type: ignore[no-untyped-def]
    plain = _shot(body, body)
    assert plain.ok and np.hypot(*(plain.measurement.corner_raw_px - TEMPLATE_PX)) < 1.0  # the rule alone: right
    checked = _shot(body, body, taught)
    assert checked.ok, f"an ordinary twin body refused {checked.refusal}: {checked.message[:400]}"
    assert np.hypot(*(checked.measurement.corner_raw_px - TEMPLATE_PX)) < 1.0
