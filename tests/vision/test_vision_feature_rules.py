"""The first shot's looser limits (cellctl.vision.feature.first_shot_limits), on the arc corner's real detection.

The first shot only aims the verification shots, so an arc's centre may be looser there: its sigma
limit is twice the first shot's corner sigma, never tighter than the arc's own limit. Truth: the
synthetic 150 mm corner of vision_test_support, its centre from arc_test_support.
"""

from __future__ import annotations

import numpy as np
import pytest
from arc_test_support import arc_centre
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.config.arc_vision import ArcCornerConfig, ArcLimitsConfig, ArcSearchConfig
from cellctl.config.vision import RoiConfig
from cellctl.vision.feature import detect_feature, first_shot_limits
from cellctl.vision.quality import Refusal

R150 = 985.0  # 150 mm on the 1024 px SMALL_LENS
CORNER, ANGLE = (1000.0, 20.0), 0.01


def _arc(max_centre_sigma_px: float) -> ArcCornerConfig:
    return ArcCornerConfig(
        expected_radius_px=R150, roi=RoiConfig(width_px=1024, height_px=1024), search=ArcSearchConfig(downscale=2),
        limits=ArcLimitsConfig(max_centre_sigma_px=max_centre_sigma_px),
    )  # fmt: skip


@pytest.fixture(scope="module")
def image() -> np.ndarray:
    rng = np.random.default_rng(7)
    return corner_image(SMALL_LENS, ideal_grid(SMALL_LENS), CORNER, ANGLE, radius_px=R150, noise_dn=2.0, blur_px=1.0, rng=rng)


def test_the_first_shot_takes_an_arc_centre_within_twice_its_corner_sigma(image: np.ndarray) -> None:
    sigma = detect_feature(image, SMALL_LENS, SMALL_CONFIG, _arc(1.0), need_orientation=False).sigma_px
    assert sigma is not None and 0.0 < sigma < 0.1
    own = _arc(0.8 * sigma)  # the arc's own limit refuses this centre
    refused = detect_feature(image, SMALL_LENS, SMALL_CONFIG, own, need_orientation=False)
    assert refused.refusal is Refusal.UNCERTAIN, refused.message
    # The first shot's corner sigma 0.6 x: the arc's is twice that, 1.2 x, and takes the centre.
    vision, arc = first_shot_limits(SMALL_CONFIG, own, 0.6 * sigma, 50)
    assert vision.limits.max_corner_sigma_px == pytest.approx(0.6 * sigma) and vision.limits.min_edge_points == 50
    shot = detect_feature(image, SMALL_LENS, vision, arc, need_orientation=False)
    assert shot.ok, shot.message
    assert np.hypot(*(np.array([shot.features.u_px, shot.features.v_px]) - arc_centre(CORNER, ANGLE, R150))) < 0.1


def test_the_first_shots_limits_are_never_tighter_than_the_arcs_own() -> None:
    _, arc = first_shot_limits(SMALL_CONFIG, _arc(0.5), 0.1, 50)
    assert arc is not None and arc.limits.max_centre_sigma_px == 0.5
    assert arc.limits.min_coverage_deg == 20.0  # the arc's own 40 deg, lowered for the first shot
    assert first_shot_limits(SMALL_CONFIG, None, 0.1, 50)[1] is None
