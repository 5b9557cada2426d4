"""RANSAC's consensus rule (cellctl.vision.lines.ransac_line), held to points whose lines are known."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.vision.lines import ransac_line

# Two runs of six points, 1 px apart: one exactly on the line v = 1, one scattered by 0.1 px about v = 0.
# Within a 0.2 px band each hypothesis through two points of a run holds that run's six points and no
# other (a line through one point of each run leans too far to hold more): a tie of counts.
SCATTERED = [(0.0, 0.0), (10.0, 0.1), (20.0, -0.1), (30.0, 0.0), (40.0, 0.1), (50.0, -0.1)]
EXACT = [(u, 1.0) for u in (5.0, 15.0, 25.0, 35.0, 45.0, 55.0)]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_tie_of_counts_goes_to_the_hypothesis_with_the_smaller_residuals(seed: int) -> None:
    points = np.array(SCATTERED + EXACT)
    mask = ransac_line(points, 0.2, 100, np.random.default_rng(seed))
    np.testing.assert_array_equal(mask, [False] * 6 + [True] * 6)


def test_the_hypothesis_with_the_most_points_in_its_band_wins_over_a_straighter_one() -> None:
    # Seven scattered points against the six exact ones: the count decides before the residuals.
    points = np.array(SCATTERED + [(60.0, 0.0)] + EXACT)
    mask = ransac_line(points, 0.2, 200, np.random.default_rng(0))
    np.testing.assert_array_equal(mask, [True] * 7 + [False] * 6)
