"""Rules of the sub-pixel stage (cellctl.vision.subpixel) on profiles of known shape."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.vision.subpixel import shape_bump


def test_a_profile_that_turns_back_inside_its_range_is_a_bump() -> None:
    # A step that rises to 0.7, falls back to 0.55 and rises on to 1: it never leaves [0, 1], its
    # turn back (0.15 of the contrast) is the bump; 400 profiles with 2 % noise.
    j = np.arange(-6, 7, dtype=float)
    shape = np.interp(j, [-6.0, -2.0, -1.0, 0.0, 1.0, 2.0, 6.0], [0.0, 0.0, 0.7, 0.55, 0.55, 1.0, 1.0])
    rows = shape + np.random.default_rng(1).normal(0.0, 0.02, (400, j.size))
    bump, noise = shape_bump(rows, 2)
    assert bump == pytest.approx(0.15, abs=0.02)
    assert bump > 8.0 * noise
