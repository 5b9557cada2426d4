"""Disturbances laid over the synthetic corner images of vision_test_support (the arc corner's tests).

Truth of the rounded corner drawn there: the arc's centre lies one radius (square px, fx on both
axes) from both edges, inside the opening; an occluder is a soft-edged rectangle (raw px) of one grey over everything.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr
from vision_test_support import SMALL_LENS

from cellctl.vision.lens import Lens


def arc_centre(corner: tuple[float, float], angle_rad: float, radius_px: float, lens: Lens = SMALL_LENS) -> NDArray[np.float64]:
    """The arc's centre (ideal px) of ``corner_image(lens, ..., corner, angle_rad, radius_px=...)``."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    # Local (x, y) = (-R, R) in square px: x along the top edge towards +u, y down the right edge.
    return np.array([corner[0] - radius_px * (c + s), corner[1] + radius_px * (c - s) * lens.fy / lens.fx])


def arc_point(centre: NDArray[np.float64], radius_px: float, angle_deg: float) -> tuple[float, float]:
    """The point of the arc at ``angle_deg`` from the centre's +u axis towards -v (0: right end, 90: top end)."""
    a = np.radians(angle_deg)
    return float(centre[0] + radius_px * np.cos(a)), float(centre[1] - radius_px * np.sin(a))


def occlude(
    image: NDArray[np.uint8], box: tuple[float, float, float, float], grey: float, blur_px: float = 0.8
) -> NDArray[np.uint8]:
    """``image`` with a rectangle (u centre, v centre, half width, half height; raw px) of ``grey`` over it."""
    v, u = np.mgrid[0 : image.shape[0], 0 : image.shape[1]].astype(np.float64)
    cu, cv, hu, hv = box
    sigma = np.hypot(blur_px, np.sqrt(1.0 / 12.0))
    cover = ndtr((hu - np.abs(u - cu)) / sigma) * ndtr((hv - np.abs(v - cv)) / sigma)
    out = image.astype(np.float64) * (1.0 - cover) + grey * cover
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def add_noise(image: NDArray[np.uint8], noise_dn: float, rng: np.random.Generator) -> NDArray[np.uint8]:
    """``image`` with Gaussian sensor noise of ``noise_dn`` (DN) added."""
    out = image.astype(np.float64) + rng.normal(0.0, noise_dn, image.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
