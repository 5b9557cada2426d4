"""The profile across an arc, and the recipe's feature edge among its concentric steps (issue 21).

A real opening's corner shows several arcs about one centre: the paint edge outside the wall's
edge, the wall's edge, the flange's and the seal's borders inside it (each band is the opening's
outline offset inwards or outwards, so its corner radius changes by the offset and its centre does
not). The arc detector's seed circle is whichever of them voted strongest. As across a straight
edge (cellctl.vision.profile), the median of many cross-sections along the arc's normals is its
profile, cut into steps, and the recipe's :class:`~cellctl.config.vision.FeatureConfig` picks the
feature among them; the sub-pixel stage then measures that arc alone.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.config.vision import FeatureConfig
from cellctl.vision.lens import Lens
from cellctl.vision.profile import SAMPLE_STEP_PX, EdgeProfile, find_steps, pick_feature

F64 = NDArray[np.float64]

__all__ = ["arc_profile"]


def arc_profile(
    image: NDArray[np.uint8], lens: Lens, centre: F64, radius: float, normals: F64, *,
    opening_darker: bool, feature: FeatureConfig,
) -> EdgeProfile:
    """The median radial profile about ``centre`` (ideal px) across the circle of ``radius``.

    ``normals`` are unit directions from the centre, in order along the arc; the profile is the
    median of ``feature.cross_sections`` of them spread evenly along it, as across a straight edge.
    Offsets are px from the circle, positive towards the centre (into the opening, as across a
    straight edge), so a step at offset o is the concentric arc of radius ``radius - o``.
    """
    normals = normals[np.unique(np.linspace(0, len(normals) - 1, min(len(normals), feature.cross_sections)).round().astype(int))]
    half = float(min(feature.profile_half_px, 0.9 * radius))
    offsets = np.arange(-half, half + 1e-9, SAMPLE_STEP_PX)
    ideal = centre[None, None, :] + (radius - offsets)[None, :, None] * normals[:, None, :]  # (S, O, 2)
    raw = lens.distort(ideal.reshape(-1, 2)).reshape(ideal.shape).astype(np.float32)
    h, w = image.shape
    inside = (raw[..., 0] >= 0) & (raw[..., 0] <= w - 1) & (raw[..., 1] >= 0) & (raw[..., 1] <= h - 1)
    values = cv2.remap(image, raw[..., 0], raw[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    counts = inside.sum(axis=0)
    levels = np.full(len(offsets), np.nan)
    enough = counts >= max(1, len(normals) // 2)
    if np.any(enough):
        masked = np.where(inside[:, enough], values[:, enough].astype(np.float64), np.nan)
        levels[enough] = np.nanmedian(masked, axis=0)
    steps = find_steps(offsets, levels)
    return EdgeProfile(offsets, levels, len(normals), steps, pick_feature(steps, opening_darker, feature))
