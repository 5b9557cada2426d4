"""The coarse stage's choice of the corner's lines (cellctl.vision.coarse), held to the drawn corner.

Truth: the synthetic corner of vision_test_support, with a longer straight edge drawn on the wall right
of it (a panel's border, a shadow): one the top edge's polarity lying right of the corner, one the right
edge's direction with the other polarity. Each would win the pairing on length if its rule were gone.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.vision import detect_corner
from cellctl.vision.coarse import CoarseCorner, find_coarse_corner


@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray]:
    return ideal_grid(SMALL_LENS)


@pytest.mark.parametrize(("corner", "step_v"), [((350.0, 600.0), 450.0), ((400.0, 600.0), 380.0)])
def test_a_longer_edge_right_of_the_corner_is_not_taken_for_the_top_edge(grid, corner: tuple[float, float], step_v: float) -> None:
    # Darker below v = step_v from 30 px right of the right edge: that edge runs 600 px, the top edge only
    # 150-200 px left of the arc; paired with the right edge it would win on length, but it lies right of
    # their crossing.
    u, v = grid
    img = corner_image(SMALL_LENS, grid, corner, 0.0, noise_dn=2.0, rng=np.random.default_rng(1)).astype(float)
    img *= 1.0 - 0.35 * ndtr((v - step_v) / 0.9) * ndtr((u - corner[0] - 30.0) / 0.9)
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    coarse = find_coarse_corner(img, SMALL_CONFIG.roi, SMALL_CONFIG.coarse, SMALL_CONFIG.opening_polarity, SMALL_LENS)
    assert isinstance(coarse, CoarseCorner), coarse.message
    assert np.linalg.norm(SMALL_LENS.undistort(coarse.corner_px[None])[0] - corner) < 5.0
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - corner) < 0.1


@pytest.mark.parametrize(("corner", "panel_u"), [((450.0, 520.0), 900.0), ((600.0, 560.0), 800.0)])
def test_a_right_edge_candidate_of_the_other_polarity_is_not_paired_with_the_top_edge(
    grid, corner: tuple[float, float], panel_u: float
) -> None:
    # The wall darkens right of u = panel_u, below v = 400: a vertical edge longer than the right edge's
    # straight part, darker on its right, so its opening side is not the top edge's.
    u, v = grid
    img = corner_image(SMALL_LENS, grid, corner, 0.0, noise_dn=2.0, rng=np.random.default_rng(1)).astype(float)
    img *= 1.0 - 0.35 * ndtr((u - panel_u) / 0.9) * ndtr((v - 400.0) / 0.9)
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    coarse = find_coarse_corner(img, SMALL_CONFIG.roi, SMALL_CONFIG.coarse, SMALL_CONFIG.opening_polarity, SMALL_LENS)
    assert isinstance(coarse, CoarseCorner), coarse.message
    assert coarse.opening_darker
    assert np.linalg.norm(SMALL_LENS.undistort(coarse.corner_px[None])[0] - corner) < 5.0
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - corner) < 0.1
