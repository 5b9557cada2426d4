"""A thin highlight running along an edge is refused, not measured as a shifted edge (review r5, D4).

Truth: synthetic corners drawn at a known place (vision_test_support) with a thin bright line on
the wall beside both edges (the ring light on the sheet's hem). Before the fix the area estimator
took the line's area for an edge shift: the corner was accepted 0.3-0.7 px off at a 0.015 px sigma.
A line well clear of the edge stays outside the sub-pixel window and changes nothing.
"""

from __future__ import annotations

import numpy as np
import pytest
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.vision import Refusal, detect_corner
from cellctl.vision.subpixel import shape_bump

CORNER = (512.0, 500.0)
WALL_DN = 150.0


@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray]:
    return ideal_grid(SMALL_LENS)


def _with_highlight(grid, offset_px: float, width_px: float, peak_dn: float) -> np.ndarray:
    """The corner with a bright line ``offset_px`` onto the wall beside the top and the right edge."""
    grey = WALL_DN + peak_dn
    marks = (
        (CORNER[0], CORNER[1] - offset_px, 0.0, width_px, grey),
        (CORNER[0] + offset_px, CORNER[1], np.pi / 2, width_px, grey),
    )
    return corner_image(SMALL_LENS, grid, CORNER, 0.0, noise_dn=1.5, rng=np.random.default_rng(3), marks=marks)


@pytest.mark.parametrize(("offset_px", "width_px", "peak_dn"), [(1.3, 1.3, 25.0), (1.3, 1.3, 15.0), (2.0, 1.0, 25.0)])
def test_a_highlight_beside_the_edge_is_refused(grid, offset_px: float, width_px: float, peak_dn: float) -> None:
    m = detect_corner(_with_highlight(grid, offset_px, width_px, peak_dn), SMALL_LENS, SMALL_CONFIG)
    # Old code: accepted, 0.31-0.69 px from the drawn corner with a sigma of 0.014-0.017 px.
    accepted_off = None if m.corner_px is None else float(np.linalg.norm(m.corner_px - np.array(CORNER)))
    assert not m.ok, f"accepted {accepted_off} px from the truth, sigma {m.corner_sigma_px}"
    assert m.refusal is Refusal.POOR_FIT
    assert "not one clean step" in m.message and "vision.fit.max_edge_bump = 0.03" in m.message
    assert "highlight" in m.message and "check the lighting" in m.message


@pytest.mark.parametrize("peak_dn", [25.0, 60.0])
def test_a_line_clear_of_the_edge_leaves_the_corner_as_it_was(grid, peak_dn: float) -> None:
    m = detect_corner(_with_highlight(grid, 13.0, 1.3, peak_dn), SMALL_LENS, SMALL_CONFIG)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - np.array(CORNER)) < 0.05


def test_a_clean_blurred_step_has_no_bump_and_a_bump_is_measured() -> None:
    j = np.arange(-6, 7, dtype=float)
    rng = np.random.default_rng(0)
    step = 0.5 * (1.0 + np.tanh(j / 1.2))  # a monotonic step, 400 profiles with 2 % noise
    rows = step + rng.normal(0.0, 0.02, (400, j.size))
    bump, noise = shape_bump(rows, 2)
    assert bump < 0.01 and 0.0005 < noise < 0.003  # 1.25 x 0.02 / 20 = 0.00125
    bumped, _ = shape_bump(rows + 0.1 * np.exp(-0.5 * ((j - 4.0) / 0.8) ** 2), 2)
    assert bumped == pytest.approx(0.1, abs=0.03)  # a tenth of the contrast past the plateau
