"""Eq. 15 (cellctl.vision.scale.scale_from_corners) over a corner grid of known spacing."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.vision.scale import scale_from_corners


def test_eq15_averages_the_pairs_along_the_rows_and_the_columns() -> None:
    # 4 rows x 6 columns of corners, 10 px apart along a row and 12.5 px down a column, squares of 5 mm:
    # 4 x 5 row pairs at 0.5 mm/px and 3 x 6 column pairs at 0.4 mm/px.
    cols, rows = np.meshgrid(np.arange(6) * 10.0, np.arange(4) * 12.5)
    grid = np.stack([100.0 + cols, 200.0 + rows], axis=2)
    s = scale_from_corners(grid, 5.0)
    assert s.n_pairs == 38
    assert s.mm_per_px == pytest.approx((20 * 0.5 + 18 * 0.4) / 38, rel=1e-12)
    assert s.mm_per_px_rows == pytest.approx(0.5) and s.mm_per_px_cols == pytest.approx(0.4)
    assert s.anisotropy == pytest.approx(0.1 / s.mm_per_px)
