"""The recipe's feature edge among several parallel edges, and marks crossing an edge (synthetic truth).

The images come from vision_test_support (independent of the twin's renderer): a paint edge on
the wall, the wall's edge, a flange and a seal's inner edge, each a blurred step at a known
offset from the true corner.
"""

from __future__ import annotations

import numpy as np
import pytest
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.config.vision import FeatureConfig, VisionConfig
from cellctl.vision import Refusal, detect_corner
from cellctl.vision.profile import find_steps, pick_feature

# Paint edge 20 px out on the wall (weak), the wall's edge at 0, a flange border 45 px in, the
# seal's inner edge 90 px in (weak): grey beyond each, from the wall (150) inwards.
REAL_STEPS = ((-20.0, 138.0), (0.0, 72.0), (45.0, 36.0), (90.0, 20.0))
SEAL_INNER = FeatureConfig(count_from="opening", index=0, min_step_fraction=0.06)
SEAL_LIMITS = SMALL_CONFIG.limits.model_copy(update={"min_contrast_dn": 8.0})  # the seal's edge is faint


@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray]:
    return ideal_grid(SMALL_LENS)


def _config(feature: FeatureConfig | None = None) -> VisionConfig:
    return SMALL_CONFIG if feature is None else SMALL_CONFIG.model_copy(update={"feature": feature})


def _inset_corner(corner: tuple[float, float], angle_rad: float, inset_px: float) -> np.ndarray:
    """The corner of the edges moved ``inset_px`` into the opening (left of the right edge, below the top)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    x, y = -inset_px, inset_px  # along the top edge (+u turned), along the right edge (down)
    return np.array([corner[0] + c * x - s * y, corner[1] + s * x + c * y])


@pytest.mark.parametrize(("corner", "angle_deg"), [((512.0, 500.0), 0.0), ((548.3, 470.6), 2.2)])
def test_the_wall_edge_is_found_among_parallel_edges(grid, corner: tuple[float, float], angle_deg: float) -> None:
    rng = np.random.default_rng(3)
    img = corner_image(SMALL_LENS, grid, corner, np.radians(angle_deg), steps=REAL_STEPS, noise_dn=2.0, rng=rng)
    m = detect_corner(img, SMALL_LENS, _config())
    assert m.ok, m.message
    # Half the clean contrast on edges half the twin's length: noise allows 0.2 px; a wrong edge is 20 px off.
    assert np.linalg.norm(m.corner_px - corner) < 0.2
    for edge in (m.top, m.right):
        assert abs(np.degrees(edge.angle_rad) - angle_deg) < 0.03
        # The profile shows all four steps at their places, relative to the picked (wall) edge.
        prof = edge.profile
        assert prof is not None and prof.feature is not None
        places = np.array([s.offset_px for s in prof.steps]) - prof.feature_step.offset_px
        for offset, _ in REAL_STEPS:
            assert np.min(np.abs(places - offset)) < 1.5, (offset, places)


def test_the_seal_inner_edge_when_the_recipe_teaches_it(grid) -> None:
    corner, angle = (512.0, 500.0), np.radians(-1.3)
    rng = np.random.default_rng(4)
    # A seal 30 DN above the interior (a faint seal is a recipe's choice: lower its limits too).
    steps = (*REAL_STEPS[:2], (45.0, 50.0), (90.0, 20.0))
    img = corner_image(SMALL_LENS, grid, corner, angle, steps=steps, noise_dn=0.5, rng=rng)
    m = detect_corner(img, SMALL_LENS, _config(SEAL_INNER).model_copy(update={"limits": SEAL_LIMITS}))
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - _inset_corner(corner, angle, 90.0)) < 0.2


def test_a_rule_that_picks_no_step_is_a_refusal_naming_the_steps(grid) -> None:
    img = corner_image(SMALL_LENS, grid, (512.0, 500.0), 0.0, steps=REAL_STEPS)
    m = detect_corner(img, SMALL_LENS, _config(FeatureConfig(index=4)))
    assert not m.ok
    assert m.refusal is Refusal.FEATURE_NOT_FOUND
    assert "step 4 counted from the wall" in m.message and "DN" in m.message


def test_a_clean_step_is_its_own_feature(grid) -> None:
    # Without bands the one step is the feature from either side.
    img = corner_image(SMALL_LENS, grid, (512.0, 500.0), 0.0)
    for feature in (FeatureConfig(), FeatureConfig(count_from="opening")):
        m = detect_corner(img, SMALL_LENS, _config(feature))
        assert m.ok, m.message
        assert np.linalg.norm(m.corner_px - (512.0, 500.0)) < 0.05


def test_steps_are_counted_by_polarity_and_size() -> None:
    x = np.arange(-100.0, 100.0, 0.5)
    # wall 150 -> 140 at -40 (weak), -> 60 at 0 (falling), -> 90 at 30 (rising), -> 20 at 60.
    y = np.full_like(x, 150.0)
    for at, change in ((-40.0, -10.0), (0.0, -80.0), (30.0, 30.0), (60.0, -70.0)):
        y += change * (x > at)
    steps = find_steps(x, y)
    assert [round(s.offset_px) for s in steps] == [-40, 0, 30, 60]
    assert [round(s.change_dn) for s in steps] == [-10, -80, 30, -70]
    assert pick_feature(steps, True, FeatureConfig()) == 1
    assert pick_feature(steps, True, FeatureConfig(index=1)) == 3
    assert pick_feature(steps, True, FeatureConfig(count_from="opening")) == 3
    assert pick_feature(steps, True, FeatureConfig(min_step_fraction=0.05)) == 0  # the weak paint edge counts
    assert pick_feature(steps, False, FeatureConfig(min_step_fraction=0.2)) == 2  # a brighter opening: rising steps
    assert pick_feature(steps, True, FeatureConfig(index=2)) is None


@pytest.mark.parametrize("grey", [10.0, 240.0])
def test_marks_crossing_an_edge_near_the_corner_are_rejected_not_refused(grid, grey: float) -> None:
    corner = (512.0, 500.0)
    rng = np.random.default_rng(5)
    # Two thin strips: one across the top edge 40 px beyond the arc, one across the arc itself.
    marks = ((corner[0] - 270.0, corner[1], np.radians(70.0), 6.0, grey), (corner[0] - 60.0, corner[1] + 60.0, np.radians(130.0), 4.0, grey))
    img = corner_image(SMALL_LENS, grid, corner, 0.0, steps=REAL_STEPS, marks=marks, noise_dn=2.0, rng=rng)
    m = detect_corner(img, SMALL_LENS, _config())
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - corner) < 0.2
    # The crossings under the mark on the top edge (u about 242 +- 3.2) were dropped, not fitted.
    kept_u = m.top.points_ideal[m.top.inliers][:, 0]
    assert not np.any(np.abs(kept_u - (corner[0] - 270.0)) < 2.0)


def test_a_mark_along_the_arc_is_left_out_of_the_circle(grid) -> None:
    # A thin dark line 1 px outside the arc, along its tangent at 45 deg: the arc looks bulged
    # there (the line merges with the opening), a monotone step in the wrong place. The circle is
    # the one most arc points agree on, so both edges still touch it.
    corner = (512.0, 500.0)
    centre, normal = np.array([312.0, 700.0]), np.array([np.sqrt(0.5), -np.sqrt(0.5)])
    on_arc = centre + 201.0 * normal
    marks = ((on_arc[0], on_arc[1], np.radians(45.0), 4.0, 20.0),)
    img = corner_image(SMALL_LENS, grid, corner, 0.0, marks=marks, noise_dn=1.0, rng=np.random.default_rng(2))
    m = detect_corner(img, SMALL_LENS, _config())
    assert m.ok, m.message
    assert abs(m.arc.gap_top_px) < 0.1 and abs(m.arc.gap_right_px) < 0.1
    assert m.arc.inliers.sum() < len(m.arc.inliers)  # the bulge's points were left out
    assert np.linalg.norm(m.corner_px - corner) < 0.1
