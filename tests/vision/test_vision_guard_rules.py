"""Rules of the corner finder the third mutation batch found unguarded, each held to a known truth.

Truth: the synthetic corners of vision_test_support (drawn corner, arc and occluder), profiles and a
lens model whose shape is worked out here by hand. Each test fails when its rule is removed.
"""

from __future__ import annotations

import numpy as np
import pytest
from arc_test_support import add_noise, arc_centre, occlude
from scipy.special import ndtr
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.config.arc_vision import ArcCornerConfig, ArcSearchConfig
from cellctl.config.vision import RoiConfig
from cellctl.vision import Refusal, detect_corner
from cellctl.vision.coarse import CoarseCorner, find_coarse_corner
from cellctl.vision.feature import detect_feature
from cellctl.vision.lens import Lens, LensFoldsOver, distort_normalised
from cellctl.vision.subpixel import _foreign


@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray]:
    return ideal_grid(SMALL_LENS)


def test_an_arc_mostly_hidden_is_refused_for_its_coverage(grid) -> None:
    # The corner (600, 420) with its 200 px arc; a box of the wall's grey over u 490-610, v 430-630 hides
    # the arc from its right end up to where u = 490 (cos a = 0.45, a = 63.3 deg): 26.7 deg of it stay in
    # view, under the 30 deg the check needs, while both straight edges (from 230 px beyond the corner) are whole.
    corner = (600.0, 420.0)
    centre = arc_centre(corner, 0.0, 200.0)
    img = corner_image(SMALL_LENS, grid, corner, 0.0, noise_dn=2.0, rng=np.random.default_rng(1))
    img = occlude(img, (centre[0] + 150.0, centre[1] - 90.0, 60.0, 100.0), 150.0)
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.arc is not None
    assert m.arc.coverage_deg == pytest.approx(90.0 - np.degrees(np.arccos(0.45)), abs=1.5)
    assert np.linalg.norm(m.corner_px - corner) < 0.1  # the edges are fine: only the arc is missing
    assert m.refusal is Refusal.ARC_NOT_SEEN
    assert m.message.startswith("refused: min arc coverage")


def test_the_corner_sigma_covers_the_scatter_of_both_edges(grid) -> None:
    # The ROI's bottom leaves the right edge about 100 px of straight run (v 530-628), the top edge about
    # 360 px: the corner's u, extrapolated 280 px from the right edge's points, scatters far more than its v.
    # Over 12 noise draws the corner's RMS distance from the drawn one matches the predicted sigma.
    corner = (600.0, 300.0)
    clean = corner_image(SMALL_LENS, grid, corner, 0.0)
    config = SMALL_CONFIG.model_copy(update={
        "roi": RoiConfig(x_px=0, y_px=0, width_px=1024, height_px=640),
        "limits": SMALL_CONFIG.limits.model_copy(update={"max_corner_sigma_px": 1.0, "min_edge_points": 50}),
    })
    errors, sigmas = [], []
    for seed in range(12):
        m = detect_corner(add_noise(clean, 4.0, np.random.default_rng(seed)), SMALL_LENS, config)
        assert m.ok, m.message
        errors.append(m.corner_px - corner)
        sigmas.append(m.corner_sigma_px)
    e = np.array(errors)
    assert np.sqrt(np.mean(e[:, 0] ** 2)) > 3.0 * np.sqrt(np.mean(e[:, 1] ** 2))  # the right edge dominates
    ratio = float(np.sqrt(np.mean(np.sum(e * e, axis=1))) / np.sqrt(np.mean(np.square(sigmas))))
    assert 0.6 < ratio < 1.6, ratio


def test_the_corner_pair_is_the_one_whose_weaker_edge_is_longest(grid) -> None:
    # The opening's corner (350, 300), radius 30, ROI down to v = 759: its top edge runs about 320 px,
    # its right edge about 430. A darker panel on the wall up and right of it (u 380-980, v 100-250) has
    # a longer top edge (600 px) but a short right edge (150 px), of the same polarity: a pair scored by
    # its longer edge would take the panel's corner (980, 100).
    u, v = grid
    corner = (350.0, 300.0)
    img = corner_image(SMALL_LENS, grid, corner, 0.0, radius_px=30.0, noise_dn=2.0, rng=np.random.default_rng(1)).astype(float)
    s = 0.9
    img *= 1.0 - 0.4 * ndtr((u - 380.0) / s) * ndtr((980.0 - u) / s) * ndtr((v - 100.0) / s) * ndtr((250.0 - v) / s)
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    roi = RoiConfig(x_px=0, y_px=0, width_px=1024, height_px=760)
    coarse = find_coarse_corner(img, roi, SMALL_CONFIG.coarse, SMALL_CONFIG.opening_polarity, SMALL_LENS)
    assert isinstance(coarse, CoarseCorner), coarse.message
    assert np.linalg.norm(SMALL_LENS.undistort(coarse.corner_px[None])[0] - corner) < 5.0
    config = SMALL_CONFIG.model_copy(update={"roi": roi, "fit": SMALL_CONFIG.fit.model_copy(update={"arc_exclusion_px": 60.0})})
    m = detect_corner(img, SMALL_LENS, config)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - corner) < 0.1


def test_the_inlier_share_counts_the_usable_points_not_every_profile(grid) -> None:
    # Over columns 20-259 of the top edge the edge is blurred to a 10 px sigma (a smear on the lens), over
    # the 4 px a profile may spread: those 240 of its about 360 profiles give no point. The 120 columns
    # left are clean and all on the line: the share of inliers among the usable points is near 1.
    u, v = grid
    corner = (600.0, 420.0)
    img = corner_image(SMALL_LENS, grid, corner, 0.0, noise_dn=2.0, rng=np.random.default_rng(1))
    smear = 150.0 - 130.0 * ndtr((v[370:470, 20:260] - corner[1]) / 10.0)
    img[370:470, 20:260] = np.rint(smear).astype(np.uint8)
    m = detect_corner(img, SMALL_LENS, SMALL_CONFIG)
    assert m.ok, m.message
    assert np.linalg.norm(m.corner_px - corner) < 0.1
    q = m.top.quality
    assert q.points < 0.5 * q.profiles  # most profiles gave no usable point
    assert q.inlier_fraction > 0.9


def test_a_window_ending_on_a_bright_line_is_foreign() -> None:
    # A blurred step from 20 to 100 DN whose last sample falls on a 255 DN line: with the far level the
    # mean of the last two samples the line lifts the contrast; the profile never turns back, but its
    # last sample lies 0.49 of the contrast over the far level, past the 0.25 a lone step allows.
    step = np.array([20, 20, 20, 22, 40, 80, 98, 100, 100, 100, 100, 100, 255], dtype=float)
    clean = step.copy()
    clean[-1] = 100.0
    values = np.vstack([step, clean])
    lo = values[:, :2].mean(axis=1)
    contrast = values[:, -2:].mean(axis=1) - lo
    np.testing.assert_array_equal(_foreign(values, lo, contrast, 2), [True, False])


def test_undistorting_past_the_fold_of_the_lens_model_is_refused() -> None:
    # k1 = 1, k2 = -1: the radial map r (1 + r^2 - r^4) rises to 1.040 at r = 0.916 and falls beyond (it
    # folds over). A raw point at r = 0.98 has two preimages: r = 0.795 before the fold (the lens's) and
    # r = 1.018 past it. Newton's method from r = 0.98 starts past the fold; it must not answer 1.018.
    lens = Lens(fx=1000.0, fy=1000.0, cx=1000.0, cy=1000.0, k1=1.0, k2=-1.0, p1=0.0, p2=0.0, k3=0.0, width_px=2000, height_px=2000)
    r = np.array([0.795, 0.916, 1.018])
    xd, _ = distort_normalised(r, np.zeros(3), lens.coefficients)
    assert xd[0] == pytest.approx(0.98, abs=1e-3) and xd[2] == pytest.approx(0.98, abs=1e-3) and xd[1] > 1.039
    raw = np.array([[1000.0 + 980.0, 1000.0]])
    try:
        ideal = lens.undistort(raw)
    except LensFoldsOver:
        return
    assert ideal[0, 0] == pytest.approx(1000.0 + 795.0, abs=2.0)


def test_an_arc_corners_edge_that_does_not_count_gives_no_angle(grid) -> None:
    # A 30 mm arc corner (700, 300), upright; a wall-grey strip over the top edge 4 px into the opening
    # (v 236-304, u < 450): the straight run seen there is the strip's border, off the arc, so it is not the
    # opening's top edge and has no angle to give; theta and the right edge's angle come from the right edge.
    corner, radius = (700.0, 300.0), 197.0
    clean = corner_image(SMALL_LENS, grid, corner, 0.0, radius_px=radius)
    img = add_noise(occlude(clean, (200.0, 270.0, 250.0, 34.0), 150.0), 2.0, np.random.default_rng(5))
    arc = ArcCornerConfig(expected_radius_px=radius, roi=RoiConfig(width_px=1024, height_px=1024), search=ArcSearchConfig(downscale=2))
    shot = detect_feature(img, SMALL_LENS, SMALL_CONFIG, arc)
    assert shot.ok and shot.features is not None, shot.message
    o = shot.measurement.orientation
    assert o.top is not None and not o.top.ok  # the strip's border was seen, and refused
    assert np.isnan(shot.features.top_angle_rad)
    assert abs(shot.features.right_angle_rad) < 5e-4 and abs(shot.features.theta_rad) < 5e-4
    assert np.hypot(*(np.array([shot.features.u_px, shot.features.v_px]) - arc_centre(corner, 0.0, radius))) < 0.1


def test_a_corner_inside_the_region_of_interest_in_the_raw_image_is_not_refused_for_its_ideal_position(grid) -> None:
    # The region of interest is in the raw image's pixels (u 0..898 here); the corner drawn at (900, 200) of the ideal
    # image lies at (897.87, 201.66) of the raw one, inside it. The check once compared the ideal position with the
    # region and refused this corner as "outside the region of interest" with every other check passed.
    img = corner_image(SMALL_LENS, grid, (900.0, 200.0), np.radians(3.0), noise_dn=2.0, rng=np.random.default_rng(1))
    cfg = SMALL_CONFIG.model_copy(update={"roi": RoiConfig(x_px=0, y_px=0, width_px=899, height_px=1024),
                                          "fit": SMALL_CONFIG.fit.model_copy(update={"arc_exclusion_px": 400.0})})  # fmt: skip
    m = detect_corner(img, SMALL_LENS, cfg)
    assert m.ok, m.message
    np.testing.assert_allclose(m.corner_px, [900.0, 200.0], atol=0.1)
    np.testing.assert_allclose(m.corner_raw_px, SMALL_LENS.distort(np.array([[900.0, 200.0]]))[0], atol=0.1)
    assert m.corner_raw_px[0] <= 898.0 < m.corner_px[0]
