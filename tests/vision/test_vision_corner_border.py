"""A corner too near the image border is refused with the cause and the fix, not raised (review r5, D2).

Truth: synthetic corners drawn at known places (vision_test_support), so near the left or bottom
border that an edge's straight part (beyond ``arc_exclusion_px``) lies outside the image. Before
the fix the feature-profile stage called cv2.remap with an empty map and raised cv2.error.
"""

from __future__ import annotations

import numpy as np
import pytest
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.vision import Refusal, detect_corner


@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray]:
    return ideal_grid(SMALL_LENS)


@pytest.mark.parametrize(
    ("corner", "side", "edge"),
    [((150.0, 500.0), "left", "top"), ((600.0, 880.0), "bottom", "right")],
)
def test_a_corner_near_the_border_is_refused_naming_the_border_and_the_fix(
    grid, corner: tuple[float, float], side: str, edge: str
) -> None:
    img = corner_image(SMALL_LENS, grid, corner, 0.0, radius_px=60.0, noise_dn=1.5, rng=np.random.default_rng(4))
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)  # old code: cv2.error (!_map1.empty() in remap)
    assert m.refusal is Refusal.EDGE_MISSING
    assert f"too near the {side} border" in m.message and f"the {edge} edge's straight part" in m.message
    assert "vision.fit.arc_exclusion_px = 230" in m.message
    assert "re-aim the camera" in m.message and "shooting pose" in m.message
    # The coarse corner is kept (to re-aim the camera) and lies on the drawn corner.
    assert m.coarse_corner_px is not None
    assert np.linalg.norm(m.coarse_corner_px - np.array(corner)) < 5.0


def test_a_corner_clear_of_the_border_is_still_measured(grid) -> None:
    corner = (512.0, 500.0)
    img = corner_image(SMALL_LENS, grid, corner, 0.0, radius_px=60.0, noise_dn=1.5, rng=np.random.default_rng(4))
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - np.array(corner)) < 0.1
