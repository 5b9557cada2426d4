"""Synthetic corner images with known truth, independent of the twin's renderer.

The opening is the quadrant left of and below the corner, rounded with radius ``radius_px``, in
square px (the ideal image with v scaled by fx / fy about the corner, where the wall's circle is
one); each raw pixel centre is undistorted with the lens, its signed distance to the rounded
quadrant taken, and the grey level is the Gaussian-blurred step there.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

from cellctl.config.vision import CoarseConfig, FitConfig, RoiConfig, VisionConfig
from cellctl.vision.lens import Lens

# A 1024 x 1024 camera with the paper's distortion and half the focal length: its edges bend
# about as much as the 2048 px camera's.
SMALL_LENS = Lens(
    fx=2625.0, fy=2624.5, cx=507.4, cy=506.0, k1=-0.158, k2=-0.0249, p1=-0.0003, p2=0.0004, k3=0.0412,
    width_px=1024, height_px=1024,
)

SMALL_CONFIG = VisionConfig(
    roi=RoiConfig(x_px=0, y_px=0, width_px=1024, height_px=1024),
    coarse=CoarseConfig(downscale=2, hough_min_length_px=100.0),
    fit=FitConfig(arc_exclusion_px=230.0),
)


def ideal_grid(lens: Lens) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Ideal (undistorted) coordinates of every raw pixel centre."""
    v, u = np.mgrid[0 : lens.height_px, 0 : lens.width_px].astype(np.float64)
    ideal = lens.undistort(np.column_stack([u.ravel(), v.ravel()]))
    return ideal[:, 0].reshape(u.shape), ideal[:, 1].reshape(u.shape)


def corner_image(
    lens: Lens,
    grid: tuple[NDArray[np.float64], NDArray[np.float64]],
    corner: tuple[float, float],
    angle_rad: float,
    *,
    radius_px: float = 200.0,
    right_extra_rad: float = 0.0,
    wall_dn: float = 150.0,
    opening_dn: float = 20.0,
    blur_px: float = 0.8,
    noise_dn: float = 0.0,
    gradient: float = 0.0,
    rng: np.random.Generator | None = None,
    edges: tuple[bool, bool] = (True, True),
    glare: tuple[float, float, float, float] | None = None,
    steps: tuple[tuple[float, float], ...] | None = None,
    marks: tuple[tuple[float, float, float, float, float], ...] = (),
) -> NDArray[np.uint8]:
    """A raw 8-bit image of the opening's upper-right corner.

    ``angle_rad`` turns the corner (the top edge's angle to u); ``right_extra_rad`` turns the right
    edge further so the corner is not square (then the corner is left sharp). ``edges`` switches
    the top and the right edge off (the opening then extends past that side). ``glare`` is
    (u, v, peak DN, sigma px) of a Gaussian veil of light added on top. ``steps`` draws several
    edges parallel to the opening's: (offset px into the opening, grey beyond it), from the wall
    inwards (negative offsets lie on the wall; the last grey is the interior's); None is the one
    step to ``opening_dn`` at 0. ``marks`` are thin strips laid over everything: (u, v, angle to u
    in rad, width px, grey), long enough to cross the whole image.
    """
    u, v = grid
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    # The shape is drawn in square px (v scaled by fx / fy), where the wall's circle images as one.
    dv = (v - corner[1]) * (lens.fx / lens.fy)
    x = c * (u - corner[0]) + s * dv  # along the top edge (towards +u)
    y = -s * (u - corner[0]) + c * dv  # along the right edge (down)
    if right_extra_rad != 0.0:
        # Sharp wedge: below the top edge and left of the turned right edge.
        ce, se = np.cos(right_extra_rad), np.sin(right_extra_rad)
        sd_right = ce * x + se * y  # distance to the right edge's line, positive right of it
        sd = np.maximum(-y, sd_right)
    else:
        dx = x + radius_px
        dy = radius_px - y
        if not edges[0]:
            dy = np.full_like(dy, -1e6)
        if not edges[1]:
            dx = np.full_like(dx, -1e6)
        outside = np.hypot(np.maximum(dx, 0.0), np.maximum(dy, 0.0))
        sd = outside + np.minimum(np.maximum(dx, dy), 0.0) - radius_px
    sigma = np.hypot(blur_px, np.sqrt(1.0 / 12.0))
    level = np.full_like(sd, wall_dn)
    before = wall_dn
    for offset, grey in steps if steps is not None else ((0.0, opening_dn),):
        level += (grey - before) * ndtr(-(sd + offset) / sigma)
        before = grey
    for mu, mv, ma, mw, grey in marks:
        across = np.abs(-np.sin(ma) * (u - mu) + np.cos(ma) * (v - mv))
        cover = ndtr((mw / 2.0 - across) / sigma)
        level += (grey - level) * cover
    if gradient:
        level = level * (1.0 + gradient * (u - lens.cx) / lens.width_px)
    if glare is not None:
        gu, gv, peak, gs = glare
        level = level + peak * np.exp(-0.5 * ((u - gu) ** 2 + (v - gv) ** 2) / gs**2)
    if noise_dn > 0:
        assert rng is not None
        level = level + rng.normal(0.0, noise_dn, level.shape)
    return np.clip(np.rint(level), 0, 255).astype(np.uint8)

