"""The arc corner's orientation from both straight edges (cellctl.vision.arc_tangent.measure_orientation).

Truth: a synthetic opening whose two straight edges are not quite square (the right edge turned
further than the top edge) with a fillet of known radius tangent to both, drawn here as
vision_test_support draws the square one (square px, raw pixel centres undistorted, a blurred step).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr
from vision_test_support import SMALL_LENS, ideal_grid

from cellctl.config.arc_vision import ArcCornerConfig, ArcSearchConfig
from cellctl.config.vision import RoiConfig
from cellctl.vision.arc_corner import detect_arc_corner
from cellctl.vision.lens import Lens

R30 = 197.0  # 30 mm on the 1024 px SMALL_LENS
CORNER = (700.0, 300.0)


def _filleted_wedge(
    lens: Lens, grid: tuple[np.ndarray, np.ndarray], angle: float, extra: float, radius: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The opening below the top edge (at ``angle`` to u) and left of the right edge (turned ``extra``
    further), its corner rounded by a circle of ``radius`` tangent to both; the image and the circle's centre (ideal px)."""
    u, v = grid
    c, s = np.cos(angle), np.sin(angle)
    dv = (v - CORNER[1]) * (lens.fx / lens.fy)
    x = c * (u - CORNER[0]) + s * dv  # along the top edge (towards +u)
    y = -s * (u - CORNER[0]) + c * dv  # down the right edge
    ce, se = np.cos(extra), np.sin(extra)
    # The rounded wedge is the sharp one eroded by the radius, then grown by it: its distance less the radius.
    vx, vy = (-radius - se * radius) / ce, radius  # the eroded wedge's vertex: the fillet's centre
    d_top, d_right = radius - y, ce * x + se * y + radius
    px, py = x - vx, y - vy
    a, b = (px * se - py * ce) / ce, px / ce  # p - V = a (0, -1) + b (ce, se): both >= 0 beyond the vertex
    sd = np.where((a >= 0) & (b >= 0), np.hypot(px, py), np.maximum(d_top, d_right)) - radius
    level = 150.0 + (20.0 - 150.0) * ndtr(-sd / np.hypot(0.8, np.sqrt(1.0 / 12.0)))
    img = np.clip(np.rint(level + rng.normal(0.0, 2.0, level.shape)), 0, 255).astype(np.uint8)
    centre = np.array([CORNER[0] + c * vx - s * vy, CORNER[1] + (s * vx + c * vy) * lens.fy / lens.fx])
    return img, centre


@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray]:
    return ideal_grid(SMALL_LENS)


@pytest.mark.parametrize(("angle_deg", "extra_deg"), [(0.5, 0.4), (-1.0, -0.6)])
def test_theta_is_the_mean_of_both_straight_edges_rotation(grid, angle_deg: float, extra_deg: float) -> None:
    angle, extra = np.radians(angle_deg), np.radians(extra_deg)
    img, centre = _filleted_wedge(SMALL_LENS, grid, angle, extra, R30, np.random.default_rng(3))
    config = ArcCornerConfig(
        expected_radius_px=R30, roi=RoiConfig(width_px=1024, height_px=1024), search=ArcSearchConfig(downscale=2)
    )
    m = detect_arc_corner(img, SMALL_LENS, config)
    assert m.ok, m.message
    assert np.hypot(*(m.centre_px - centre)) < 0.1
    o = m.orientation
    assert o.top is not None and o.top.ok and o.right is not None and o.right.ok, o.reason
    assert np.degrees(o.top.angle_rad) == pytest.approx(angle_deg, abs=0.01)
    assert np.degrees(o.right.angle_rad) == pytest.approx(angle_deg + extra_deg, abs=0.01)
    assert np.degrees(o.theta_rad) == pytest.approx(angle_deg + extra_deg / 2.0, abs=0.01)
