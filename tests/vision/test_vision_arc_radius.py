"""The corner's arc check holds the arc's radius to the recipe's (review r4, D2).

A second strong edge beside the top edge (a shadow or sealant band 55-70 px wide on the wall) can
pull the feature rule onto the band's border; a circle about 1.35 times the drawn radius then
touches both lines and the tangency check passes by chance. Truth: the synthetic renderer's drawn
corner and radius (vision_test_support), the camera's fx and working distance for the recipe's.
"""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.config import load_config
from cellctl.config.feature import CornerRadius, shot_feature
from cellctl.config.vision import FeatureConfig, LimitsConfig
from cellctl.vision import Refusal, detect_corner
from cellctl.vision.feature import detect_feature

TRUTH = np.array([512.0, 500.0])
DRAWN_RADIUS = CornerRadius(200.0, "layout.opening.corner_radius_mm 15.24 mm at 0.0762 mm/px")


@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray]:
    return ideal_grid(SMALL_LENS)


def _band_image(grid, band_px: float, seed: int) -> np.ndarray:
    """The corner with a dark band (40 DN) ``band_px`` wide on the wall right above the top edge."""
    mark = (0.0, TRUTH[1] - band_px / 2, 0.0, band_px, 40.0)
    return corner_image(SMALL_LENS, grid, tuple(TRUTH), 0.0, noise_dn=2, rng=np.random.default_rng(seed), marks=(mark,))


@pytest.mark.parametrize(("band_px", "seed"), [(55, 1), (60, 2), (65, 1), (70, 3)])
def test_a_band_beside_the_top_edge_is_refused_naming_the_radii(grid, band_px: int, seed: int) -> None:
    # These images gave "corner found" band_px off the truth without the radius check.
    m = detect_corner(_band_image(grid, band_px, seed), SMALL_LENS, SMALL_CONFIG, DRAWN_RADIUS)
    assert m.refusal is Refusal.ARC_MISMATCH, (m.message, None if m.corner_px is None else m.corner_px - TRUTH)
    assert "expected 200 px (layout.opening.corner_radius_mm 15.24 mm at 0.0762 mm/px)" in m.message
    assert "vision.limits.arc_radius_tolerance" in m.message
    assert m.arc is not None and abs(m.arc.radius_px / 200.0 - 1.0) > 0.25  # the fitted circle is the wrong one


@pytest.mark.parametrize(("corner", "angle_deg", "radius"), [((512.0, 500.0), 0.0, 200.0), ((600.0, 420.0), 6.0, 150.0)])
def test_a_good_corner_is_measured_as_before(grid, corner: tuple[float, float], angle_deg: float, radius: float) -> None:
    rng = np.random.default_rng(4)
    img = corner_image(SMALL_LENS, grid, corner, np.radians(angle_deg), radius_px=radius, noise_dn=2, rng=rng)
    expected = CornerRadius(radius, "the drawn radius")
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG, expected)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - np.array(corner)) < 0.1
    plain = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert np.array_equal(plain.corner_px, m.corner_px)


def test_a_recipe_radius_that_is_not_the_opening_is_refused(grid) -> None:
    img = corner_image(SMALL_LENS, grid, tuple(TRUTH), 0.0, noise_dn=2, rng=np.random.default_rng(5))
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG, CornerRadius(240.0, "layout.opening.corner_radius_mm"))
    assert m.refusal is Refusal.ARC_MISMATCH and "arc radius 200 px, expected 240 px" in m.message
    loose = SMALL_CONFIG.model_copy(update={"limits": LimitsConfig(arc_radius_tolerance=0.25)})
    assert detect_corner(img, SMALL_LENS, loose, CornerRadius(240.0, "layout")).ok


def test_a_seal_feature_expects_the_concentric_arc_inside_the_opening(grid) -> None:
    # Wall's edge at 0, the seal's inner edge 60 px into the opening: its arc is 200 - 60 px.
    img = corner_image(SMALL_LENS, grid, tuple(TRUTH), 0.0, steps=((0.0, 70.0), (60.0, 20.0)), noise_dn=1,
                       rng=np.random.default_rng(6))  # fmt: skip
    seal = FeatureConfig(count_from="opening", index=0, min_step_fraction=0.2)
    config = SMALL_CONFIG.model_copy(update={"feature": seal})
    m = detect_corner(img, SMALL_LENS, config, DRAWN_RADIUS)
    assert m.ok, m.message
    assert abs(m.arc.radius_px - 140.0) < 1.0
    assert np.linalg.norm(m.corner_px - (TRUTH + np.array([-60.0, 60.0]))) < 0.2


def test_the_feature_passes_the_recipes_radius_to_the_corner_detector(grid) -> None:
    img = _band_image(grid, 60, 2)
    assert detect_feature(img, SMALL_LENS, SMALL_CONFIG, None).ok  # the old answer: 60 px off
    shot = detect_feature(img, SMALL_LENS, SMALL_CONFIG, None, corner_radius=DRAWN_RADIUS)
    assert shot.refusal is Refusal.ARC_MISMATCH and shot.features is None


def test_the_corner_recipe_expects_its_radius_at_the_nominal_scale() -> None:
    config = load_config("config/sim.toml")
    view = config.for_recipe(config.default_recipe)
    expected = shot_feature(view).corner_radius
    assert expected is not None
    cam, wd = view.layout.camera, view.process.working_distance_mm
    assert abs(expected.radius_px - view.layout.opening.corner_radius_mm * cam.fx / wd) < 1e-9
    assert "layout.opening.corner_radius_mm 30 mm at 0.07619 mm/px" == expected.source


@pytest.mark.parametrize("bad", [0.0, -0.1, 0.6, float("nan")])
def test_the_tolerance_is_validated(bad: float) -> None:
    with pytest.raises(ValidationError, match="arc_radius_tolerance"):
        LimitsConfig(arc_radius_tolerance=bad)
