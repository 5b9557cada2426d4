"""Rules of one edge's measurement (cellctl.vision.edge) on profiles whose disturbance is known (drawn here
or by vision_test_support)."""

from __future__ import annotations

import numpy as np
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.vision import detect_corner
from cellctl.vision.edge import background_consistent


def test_the_undisturbed_level_ratio_is_the_densest_not_the_median() -> None:
    # 100 profiles along an edge, opening 20 DN and wall 150 DN (ratio 0.133); a glare veil adds
    # 30-200 DN to both levels of 60 of them, rising along the edge: their ratios spread over
    # 0.28-0.63, so they outnumber the undisturbed ones but no 0.2-wide window holds as many.
    rng = np.random.default_rng(2)
    n = 100
    glare = np.zeros(n)
    disturbed = np.zeros(n, dtype=bool)
    disturbed[40:] = True
    glare[40:] = np.linspace(30.0, 200.0, 60)
    opening = 20.0 + glare + rng.normal(0.0, 0.3, n)
    wall = 150.0 + glare + rng.normal(0.0, 0.3, n)
    keep = background_consistent((opening, wall), np.ones(n, dtype=bool), 0.1)
    np.testing.assert_array_equal(keep, ~disturbed)
    # The levels' order does not matter (the ratio is darker over brighter), nor the profiles' given mask.
    mask = np.ones(n, dtype=bool)
    mask[5] = False
    keep = background_consistent((wall, opening), mask, 0.1)
    np.testing.assert_array_equal(keep, ~disturbed & mask)


def test_profiles_of_the_wrong_polarity_are_left_out() -> None:
    # Over columns 150-199 of the top edge the wall side is dark and the opening side bright (a dark
    # object before a bright one): a clean step of the edge's levels, but turned, so it is not the edge.
    corner = (600.0, 420.0)
    img = corner_image(SMALL_LENS, ideal_grid(SMALL_LENS), corner, 0.0, noise_dn=2.0, rng=np.random.default_rng(1))
    img[380:460, 150:200] = 170 - img[380:460, 150:200]
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - corner) < 0.1
    columns = m.top.points_raw[:, 0]
    assert not np.any((columns >= 150.0) & (columns <= 199.0))
    assert np.sum((columns >= 100.0) & (columns <= 149.0)) == 50  # the columns beside it are measured
