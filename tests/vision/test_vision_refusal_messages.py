"""Refusals say the cause and the setting (review r4, D3): a dark or saturated frame, an edge past the tilt limit.

Truth: frames of known levels, and the synthetic renderer's corner turned by a known angle.
"""

from __future__ import annotations

import numpy as np
import pytest
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.config.vision import CoarseConfig
from cellctl.vision import Refusal, detect_corner


def test_a_black_frame_says_it_is_too_dark_and_what_to_check() -> None:
    m = detect_corner(np.zeros((1024, 1024), np.uint8), SMALL_LENS, SMALL_CONFIG)
    assert m.refusal is Refusal.CORNER_NOT_FOUND
    assert "too dark (mean 0 DN" in m.message
    assert "lens cap" in m.message and "devices.camera.exposure_us" in m.message


def test_a_nearly_black_frame_is_too_dark_too() -> None:
    img = np.random.default_rng(1).integers(0, 12, (1024, 1024)).astype(np.uint8)  # sensor noise, light off
    assert "too dark" in detect_corner(img, SMALL_LENS, SMALL_CONFIG).message


def test_a_white_frame_says_it_is_saturated() -> None:
    m = detect_corner(np.full((1024, 1024), 255, np.uint8), SMALL_LENS, SMALL_CONFIG)
    assert not m.ok
    assert "saturated" in m.message and "mean 255 DN" in m.message and "devices.camera.exposure_us" in m.message


def test_a_plain_wall_is_neither_dark_nor_saturated() -> None:
    m = detect_corner(np.full((1024, 1024), 90, np.uint8), SMALL_LENS, SMALL_CONFIG)
    assert "no straight edge" in m.message and "mean 90 DN" in m.message
    assert "dark" not in m.message and "saturated" not in m.message


@pytest.mark.parametrize("angle_deg", [13.0, -15.0])
def test_an_edge_leaning_past_the_limit_names_the_setting(angle_deg: float) -> None:
    img = corner_image(SMALL_LENS, ideal_grid(SMALL_LENS), (512.0, 500.0), np.radians(angle_deg), noise_dn=2,
                       rng=np.random.default_rng(3))  # fmt: skip
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.refusal is Refusal.EDGE_MISSING
    assert "vision.coarse.max_tilt_deg (12 deg)" in m.message
    lean = float(m.message.split(" deg from the image rows")[0].split("-")[-1])
    assert abs(lean - abs(angle_deg)) < 1.0  # the leaning edge's angle, as drawn
    # Raising the limit as the message says finds the corner.
    wide = SMALL_CONFIG.model_copy(update={"coarse": CoarseConfig(downscale=2, hough_min_length_px=100.0, max_tilt_deg=20.0)})
    assert detect_corner(img, SMALL_LENS, wide).refusal is not Refusal.EDGE_MISSING
