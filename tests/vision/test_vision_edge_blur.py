"""A blurred frame is refused naming the blur, its setting and the fix (review r5, D5).

Truth: synthetic corners drawn with a known Gaussian blur or smeared by a known motion (a box
of 15 px across the top edge), and the twin's own defocus. Before the fix the refusal read
"min top edge points 0 (limit: at least 100)", naming neither the blur nor the setting.
"""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.bench.vision import shooting_scene
from cellctl.config.render import DisturbanceConfig
from cellctl.config.sim import SimConfig
from cellctl.config.vision import VisionConfig
from cellctl.sim.camera import CameraRenderer
from cellctl.vision import Refusal, detect_corner
from cellctl.vision.lens import Lens

CORNER = (512.0, 500.0)


@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray]:
    return ideal_grid(SMALL_LENS)


def _spread(message: str) -> float:
    found = re.search(r"its spread is ([0-9.]+) px", message)
    assert found, message
    return float(found.group(1))


def _says_blur(message: str) -> None:
    assert "blurred" in message and "vision.fit.max_blur_sigma_px = 4 px" in message, message
    assert "focus" in message and "come to rest before the shot" in message, message


def test_a_defocused_corner_is_refused_naming_the_blur(grid) -> None:
    img = corner_image(SMALL_LENS, grid, CORNER, 0.0, blur_px=6.0, noise_dn=1.5, rng=np.random.default_rng(2))
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.refusal is Refusal.EDGE_MISSING
    _says_blur(m.message)
    assert _spread(m.message) == pytest.approx(6.0, rel=0.15)  # the blur drawn (pixel footprint included)


def test_a_motion_blurred_corner_is_refused_naming_the_blur(grid) -> None:
    img = corner_image(SMALL_LENS, grid, CORNER, 0.0, noise_dn=1.5, rng=np.random.default_rng(2))
    smeared = cv2.blur(img, (1, 15))  # the camera moved 15 px along v during the exposure
    m = detect_corner(smeared, SMALL_LENS, SMALL_CONFIG)
    assert m.refusal is Refusal.EDGE_MISSING
    _says_blur(m.message)
    assert "top edge is blurred" in m.message
    assert _spread(m.message) > 4.0  # a 15 px box: 4.3 px standard deviation


def test_a_slightly_blurred_corner_is_still_measured(grid) -> None:
    img = corner_image(SMALL_LENS, grid, CORNER, 0.0, blur_px=2.0, noise_dn=1.5, rng=np.random.default_rng(2))
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - np.array(CORNER)) < 0.1


def test_the_twins_defocused_frame_is_refused_naming_the_blur() -> None:
    sim = SimConfig()
    intr = sim.camera.intrinsics
    r = CameraRenderer(intr, sim.camera.render.model_copy(update={"disturbances": DisturbanceConfig(defocus_sigma_px=6.0)}))
    rng = np.random.default_rng(8)
    world, pose = shooting_scene(r, sim, rng)
    m = detect_corner(r.render(pose, world, rng=rng).image, Lens.from_intrinsics(intr), VisionConfig())
    assert m.refusal is Refusal.EDGE_MISSING
    _says_blur(m.message)
    assert 5.0 < _spread(m.message) < 7.0  # the twin's defocus of 6 px
