"""Rules of the corner detector a mutation run found unguarded, held to the synthetic images' truth.

Each test fails when its rule is removed: theta is the mean of both edges' rotations; a figure
equal to its limit passes (the limits read "at least" and "at most").
"""

from __future__ import annotations

import numpy as np
import pytest
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.vision import Refusal, detect_corner
from cellctl.vision.quality import at_least, at_most


@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray]:
    return ideal_grid(SMALL_LENS)


def test_theta_is_the_mean_of_the_top_and_the_right_edges_rotation(grid) -> None:
    # A sharp corner whose right edge is turned 0.6 deg further than its top edge (within the right
    # angle's tolerance): the top edge lies at 1.5 deg to u, the right edge at 2.1 deg to v, theta halfway.
    angle, extra = np.radians(1.5), np.radians(0.6)
    img = corner_image(SMALL_LENS, grid, (520.0, 490.0), angle, right_extra_rad=extra, noise_dn=1.0, rng=np.random.default_rng(3))
    config = SMALL_CONFIG.model_copy(update={"fit": SMALL_CONFIG.fit.model_copy(update={"check_arc": False})})
    m = detect_corner(img, SMALL_LENS, config)
    assert m.ok, m.message
    assert np.degrees(m.top.angle_rad) == pytest.approx(1.5, abs=0.01)
    assert np.degrees(m.right.angle_rad) == pytest.approx(2.1, abs=0.01)
    assert np.degrees(m.theta_rad) == pytest.approx(1.8, abs=0.01)
    assert np.degrees(m.features.theta_rad) == pytest.approx(1.8, abs=0.01)


@pytest.mark.parametrize("value", [0.5, 100.0])
def test_a_figure_equal_to_its_limit_passes(value: float) -> None:
    assert at_least("edge points", value, value, Refusal.EDGE_MISSING).passed
    assert at_most("fit RMS", value, value, Refusal.POOR_FIT).passed
    assert not at_least("edge points", np.nextafter(value, 0.0), value, Refusal.EDGE_MISSING).passed
    assert not at_most("fit RMS", np.nextafter(value, np.inf), value, Refusal.POOR_FIT).passed
