"""The annotated pictures draw a refused fit's far-off centre without failing.

A refused arc fit's centre can lie ~1e9 px off the image (the twin gave (-4.8e8, 7.6e9) px for a glass turned
3 deg); OpenCV takes int32 pixels, so drawing it raised and the cycle's record said "software fault" instead
of the inspection's refusal. Truth: the picture itself, decoded from the PNG (what is drawn where).
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from vision_test_support import SMALL_CONFIG, SMALL_LENS, corner_image, ideal_grid

from cellctl.config.vision import RoiConfig
from cellctl.vision import annotate
from cellctl.vision.annotate_arc import annotate_arc
from cellctl.vision.arc_corner import ArcCornerMeasurement
from cellctl.vision.corner import CornerFeatures, detect_corner
from cellctl.vision.quality import Refusal

FAR = np.array([-4.8e8, 7.6e9])  # the twin's refused opening arc (px)
MAGENTA, CYAN = (255, 0, 255), (255, 255, 0)  # BGR, as annotate draws them


def _mask(picture: np.ndarray, colour: tuple[int, int, int]) -> np.ndarray:
    return np.all(np.abs(picture.astype(int) - np.array(colour)) <= 40, axis=2)


def _picture(png: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)


def _refused(centre: np.ndarray | None) -> ArcCornerMeasurement:
    return ArcCornerMeasurement(Refusal.POOR_FIT, "the arc's points scatter", centre_px=centre, radius_px=5.0e9)


@pytest.mark.parametrize("centre", [FAR, np.array([np.nan, 300.0]), np.array([np.inf, -np.inf])])
def test_a_refused_arc_with_its_centre_far_off_or_not_finite_is_drawn_without_its_centre(centre: np.ndarray) -> None:
    image = np.full((1024, 1024), 90, np.uint8)
    taught = CornerFeatures(600.0, 400.0, 0.0, 0.0, 0.0)
    picture = _picture(annotate_arc(image, _refused(centre), SMALL_LENS, RoiConfig(width_px=1024, height_px=1024),
                                    taught=taught, width_px=512))  # fmt: skip
    assert picture.shape == (512, 512, 3)
    magenta = np.argwhere(_mask(picture, MAGENTA))  # the taught cross only: no arrow towards a centre not drawn
    assert len(magenta) > 0
    raw = SMALL_LENS.distort(np.array([[600.0, 400.0]]))[0] / 2.0  # the picture is half size
    assert np.all(np.abs(magenta[:, ::-1] - raw) <= 14), "magenta drawn away from the taught cross"
    assert not _mask(picture[60:], CYAN).any()  # no centre cross (the caption's top rows aside)


def test_a_centre_just_off_the_image_gets_its_arrow_clipped_to_the_border() -> None:
    image = np.full((1024, 1024), 90, np.uint8)
    taught = CornerFeatures(600.0, 500.0, 0.0, 0.0, 0.0)
    centre = np.array([-400.0, 500.0])  # 400 px left of the image (within one image size): the arrow leaves the picture
    picture = _picture(annotate_arc(image, _refused(centre), SMALL_LENS, RoiConfig(width_px=1024, height_px=1024),
                                    taught=taught, width_px=512))  # fmt: skip
    magenta = _mask(picture, MAGENTA)
    row = int(round(SMALL_LENS.distort(np.array([[0.0, 500.0]]))[0][1] / 2.0))
    assert magenta[row - 3 : row + 4, :3].any()  # the arrow's line reaches the picture's left border


def test_the_corner_picture_draws_a_far_corner_without_failing() -> None:
    grid = ideal_grid(SMALL_LENS)
    image = corner_image(SMALL_LENS, grid, (600.0, 400.0), 0.01, noise_dn=1.0, rng=np.random.default_rng(3))
    m = detect_corner(image, SMALL_LENS, SMALL_CONFIG)
    assert m.ok, m.message
    far = dataclasses.replace(m, refusal=Refusal.NOT_PERPENDICULAR, message="the edges do not meet at a right angle",
                              corner_px=FAR, corner_raw_px=FAR)  # fmt: skip
    picture = _picture(annotate(image, far, SMALL_LENS, taught=CornerFeatures(600.0, 400.0, 0.0, 0.0, 0.0), width_px=512))
    assert picture.shape == (512, 512, 3)
    assert not _mask(picture[60:], CYAN).any()
