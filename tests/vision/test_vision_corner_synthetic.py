"""The corner detector on synthetic images with exact truth: accuracy, refusals, bad calls."""

from __future__ import annotations

import numpy as np
import pytest
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.config.vision import LimitsConfig, RoiConfig, VisionConfig
from cellctl.vision import Refusal, annotate, detect_corner
from cellctl.vision.coarse import CoarseFailure, find_coarse_corner
from cellctl.vision.lens import Lens


@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray]:
    return ideal_grid(SMALL_LENS)


@pytest.mark.parametrize(
    ("corner", "angle_deg"),
    [((512.0, 500.0), 0.0), ((560.3, 430.7), 1.7), ((455.55, 575.25), -2.4), ((610.0, 610.0), 6.0)],
)
def test_corner_and_angle_match_the_truth(grid, corner: tuple[float, float], angle_deg: float) -> None:
    rng = np.random.default_rng(11)
    img = corner_image(SMALL_LENS, grid, corner, np.radians(angle_deg), noise_dn=2.0, gradient=0.1, rng=rng)
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - corner) < 0.08
    np.testing.assert_allclose(m.corner_raw_px, SMALL_LENS.distort(np.array([corner]))[0], atol=0.08)
    for edge in (m.top, m.right):
        assert abs(np.degrees(edge.angle_rad) - angle_deg) < 0.01
        assert edge.quality.inlier_fraction > 0.95
        assert 0.03 < edge.quality.rms_px < 0.2
        assert edge.quality.contrast_dn == pytest.approx(130.0, abs=8.0)
    assert np.degrees(m.theta_rad) == pytest.approx(angle_deg, abs=0.01)
    assert np.degrees(m.corner_angle_rad) == pytest.approx(90.0, abs=0.02)
    assert m.corner_sigma_px < 0.05
    f = m.features
    assert (f.u_px, f.v_px) == (m.corner_px[0], m.corner_px[1])
    assert all(c.passed for c in m.checks)


def test_the_arc_is_left_out(grid) -> None:
    # With the arc excluded, a tight corner radius or a wide one give the same corner.
    corner = (520.0, 505.0)
    for radius in (60.0, 200.0):
        img = corner_image(SMALL_LENS, grid, corner, 0.01, radius_px=radius)
        m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
        assert m.ok, m.message
        assert np.linalg.norm(m.corner_px - corner) < 0.03
        # No fitted point lies within the arc exclusion distance of the corner.
        for edge in (m.top, m.right):
            assert edge.line.along(edge.points_ideal).min() >= edge.line.along(m.corner_px[None])[0] + 229.0


def test_arc_points_inside_a_too_small_exclusion_become_outliers(grid) -> None:
    # If the recipe's exclusion is smaller than the arc, RANSAC and the robust band still drop
    # the arc's points (they leave the line quadratically), so the corner stays right.
    rng = np.random.default_rng(8)
    img = corner_image(SMALL_LENS, grid, (512.0, 500.0), 0.0, radius_px=200.0, noise_dn=2.0, rng=rng)
    cfg = SMALL_CONFIG.model_copy(update={"fit": SMALL_CONFIG.fit.model_copy(update={"arc_exclusion_px": 100.0})})
    m = detect_corner(img, SMALL_LENS, cfg)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - (512.0, 500.0)) < 0.08
    for edge in (m.top, m.right):
        t = edge.line.along(edge.points_ideal) - edge.line.along(m.corner_px[None])[0]
        on_arc = t < 180.0  # more than 1 px off the line
        assert on_arc.sum() > 50 and not np.any(edge.inliers[on_arc])


def test_profiles_under_a_glare_veil_are_left_out(grid) -> None:
    # A veil of light on the top edge: there the opening/wall level ratio departs from the
    # edge's, so those profiles are dropped instead of biasing the line.
    rng = np.random.default_rng(12)
    corner = (600.0, 420.0)
    img = corner_image(SMALL_LENS, grid, corner, 0.0, noise_dn=2.0, rng=rng, glare=(260.0, 425.0, 80.0, 40.0))
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.ok, m.message
    assert m.top.quality.uneven_background > 60 and m.right.quality.uneven_background == 0
    assert not np.any(np.abs(m.top.points_raw[:, 0] - 260.0) < 40.0)
    assert np.linalg.norm(m.corner_px - corner) < 0.1


def test_an_empty_image_is_refused_not_raised() -> None:
    m = detect_corner(np.full((1024, 1024), 90, np.uint8), SMALL_LENS, SMALL_CONFIG)
    assert m.refusal is Refusal.CORNER_NOT_FOUND
    assert "no straight edge" in m.message
    with pytest.raises(ValueError, match="refused"):
        _ = m.features
    png = annotate(np.full((1024, 1024), 90, np.uint8), m, SMALL_LENS)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_missing_edge_is_refused(grid) -> None:
    img = corner_image(SMALL_LENS, grid, (512.0, 500.0), 0.0, edges=(True, False))
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.refusal is Refusal.EDGE_MISSING
    assert "right edge" in m.message


def test_low_contrast_is_refused(grid) -> None:
    rng = np.random.default_rng(4)
    img = corner_image(SMALL_LENS, grid, (512.0, 500.0), 0.0, wall_dn=95.0, opening_dn=82.0, noise_dn=1.0, rng=rng)
    cfg = SMALL_CONFIG.model_copy(update={"coarse": SMALL_CONFIG.coarse.model_copy(update={"canny_low": 5.0, "canny_high": 10.0})})
    m = detect_corner(img, SMALL_LENS, cfg)
    assert m.refusal is Refusal.LOW_CONTRAST
    assert "contrast" in m.message and "limit" in m.message


def test_a_corner_that_is_not_square_is_refused(grid) -> None:
    img = corner_image(SMALL_LENS, grid, (512.0, 500.0), 0.0, right_extra_rad=np.radians(3.0))
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.refusal is Refusal.NOT_PERPENDICULAR
    assert np.degrees(m.corner_angle_rad) == pytest.approx(87.0, abs=0.05)
    # Within a looser tolerance the same corner passes that check; being sharp, it has no arc to
    # check the edges against, which is a refusal of its own unless the arc check is off.
    loose = SMALL_CONFIG.model_copy(update={"limits": LimitsConfig(perpendicular_tolerance_deg=5.0)})
    assert detect_corner(img, SMALL_LENS, loose).refusal is Refusal.ARC_NOT_SEEN
    no_arc = loose.model_copy(update={"fit": loose.fit.model_copy(update={"check_arc": False})})
    m = detect_corner(img, SMALL_LENS, no_arc)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - (512.0, 500.0)) < 0.05


def test_the_polarity_the_recipe_expects(grid) -> None:
    img = 170 - corner_image(SMALL_LENS, grid, (512.0, 500.0), 0.0)  # a bright opening
    assert detect_corner(img, SMALL_LENS, SMALL_CONFIG).refusal is Refusal.CORNER_NOT_FOUND
    auto = SMALL_CONFIG.model_copy(update={"opening_polarity": "auto"})
    m = detect_corner(img, SMALL_LENS, auto)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - (512.0, 500.0)) < 0.03


def test_the_roi_limits_the_search(grid) -> None:
    img = corner_image(SMALL_LENS, grid, (512.0, 500.0), 0.0)
    away = SMALL_CONFIG.model_copy(update={"roi": RoiConfig(x_px=600, y_px=0, width_px=424, height_px=400)})
    assert not detect_corner(img, SMALL_LENS, away).ok
    around = SMALL_CONFIG.model_copy(update={"roi": RoiConfig(x_px=100, y_px=120, width_px=800, height_px=800)})
    m = detect_corner(img, SMALL_LENS, around)
    assert m.ok, m.message
    assert np.all(m.top.points_raw[:, 0] >= 100 + 12) and np.all(m.right.points_raw[:, 1] <= 120 + 800 - 13)


def test_a_wrong_call_raises_a_clear_error(grid) -> None:
    img = corner_image(SMALL_LENS, grid, (512.0, 500.0), 0.0)
    with pytest.raises(ValueError, match="uint8"):
        detect_corner(img.astype(np.float32), SMALL_LENS, SMALL_CONFIG)
    with pytest.raises(ValueError, match="calibrated for 1024 x 1024"):
        detect_corner(img[:512], SMALL_LENS, SMALL_CONFIG)
    with pytest.raises(ValueError, match="vision.roi"):
        detect_corner(img, SMALL_LENS, VisionConfig())  # the default ROI is for 2048 px


def test_the_coarse_right_angle_is_judged_in_the_ideal_image() -> None:
    """A square corner near the border of a wide-angle lens's image: its raw edges meet more than
    3 deg off a right angle, the ideal ones at one; the corner is found there, at its true place."""
    lens = Lens(fx=1100.0, fy=1100.0, cx=512.0, cy=512.0, k1=-0.3, k2=0.0, p1=0.0, p2=0.0, k3=0.0, width_px=1024, height_px=1024)
    config = SMALL_CONFIG.model_copy(update={"fit": SMALL_CONFIG.fit.model_copy(update={"arc_exclusion_px": 80.0})})
    img = corner_image(lens, ideal_grid(lens), (300.0, 700.0), 0.0, radius_px=60.0)
    raw = find_coarse_corner(img, config.roi, config.coarse, config.opening_polarity)
    assert isinstance(raw, CoarseFailure) and "right angle" in raw.message  # judged on raw pixels: refused
    m = detect_corner(img, lens, config)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - (300.0, 700.0)) < 0.01
