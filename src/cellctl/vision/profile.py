"""The profile across a straight edge, its steps, and the recipe's feature edge among them.

A real opening shows several edges running parallel to each other: a paint edge on the wall,
the wall's own edge, the border of a recessed flange, the inner edge of a rubber seal. The
coarse stage finds one of them; which one is the feature is the recipe's choice
(:class:`cellctl.config.vision.FeatureConfig`).

Across a straight edge, cross-sections are sampled in the ideal (undistorted) image along the
edge's normal at many places along it, and their median is the edge's profile: a mark or a dirt
spot that crosses a few cross-sections does not move it. The profile is smoothed, its slope is
cut into lobes of one sign, and each lobe is a step whose size is the level change over it and
whose place is the slope-weighted centre of the lobe. The steps of the opening's polarity that
are large enough are counted from the wall or from the opening, and the recipe's index picks the
feature. Places are only good to a pixel or so: they seed the sub-pixel stage, which measures
the chosen edge alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.config.vision import FeatureConfig
from cellctl.vision.lens import Lens
from cellctl.vision.lines import Line2D

F64 = NDArray[np.float64]

SAMPLE_STEP_PX = 1.0
_SMOOTH_SIGMA_PX = 1.5
_MIN_STEP_FRACTION = 0.03  # lobes of the slope smaller than this share of the range are noise


@dataclass(frozen=True)
class ProfileStep:
    """One step of an edge's profile.

    ``offset_px``: its place along the edge's normal from the line the profile was taken about,
    positive into the opening; ``change_dn``: the level after it minus the level before it,
    going into the opening (negative for a step that darkens towards the opening);
    ``fraction``: its size over the profile's whole range.
    """

    offset_px: float
    change_dn: float
    fraction: float


@dataclass(frozen=True)
class EdgeProfile:
    """The median profile across one straight edge and the steps found on it.

    ``offsets_px`` are the sample places (positive into the opening), ``levels_dn`` the median
    over ``sections`` cross-sections (NaN where fewer than half of them were inside the image).
    ``feature`` is the index in ``steps`` of the step the recipe picks, or None.
    """

    offsets_px: F64
    levels_dn: F64
    sections: int
    steps: tuple[ProfileStep, ...]
    feature: int | None

    @property
    def feature_step(self) -> ProfileStep | None:
        return None if self.feature is None else self.steps[self.feature]


def into_opening(line: Line2D, name: str) -> F64:
    """The unit normal of an edge's line that points into the opening (down for top, left for right)."""
    n = line.normal
    towards = np.array([0.0, 1.0]) if name == "top" else np.array([-1.0, 0.0])
    return n if float(n @ towards) >= 0.0 else -n


def sample_profile(
    image: NDArray[np.uint8],
    lens: Lens,
    line: Line2D,
    inward: F64,
    along_px: F64,
    half_px: float,
) -> tuple[F64, F64]:
    """Median cross-section of ``image`` across ``line`` (ideal image), at places ``along_px`` on it.

    Returns (offsets, median levels); a sample is bilinear in the raw image at the distorted
    place; places outside the image count as missing.
    """
    offsets = np.arange(-half_px, half_px + 1e-9, SAMPLE_STEP_PX)
    base = line.point + along_px[:, None] * line.direction  # (S, 2)
    # Each cross-section's raw path through three distorted points (its ends and middle): the
    # lens bends a path of this length by far less than a pixel from that parabola, which is
    # all the profile needs, at a fraction of distorting every sample.
    ends = np.stack([base - half_px * inward, base, base + half_px * inward], axis=1)  # (S, 3, 2)
    r0, r1, r2 = (lens.distort(ends.reshape(-1, 2)).reshape(ends.shape)[:, k, :] for k in range(3))
    t = (offsets / half_px).astype(np.float32)[None, :, None]  # -1 .. 1
    a, b, c = (x.astype(np.float32)[:, None, :] for x in (r1, 0.5 * (r2 - r0), 0.5 * (r2 + r0 - 2.0 * r1)))
    raw = a + t * (b + t * c)
    h, w = image.shape
    inside = (raw[..., 0] >= 0) & (raw[..., 0] <= w - 1) & (raw[..., 1] >= 0) & (raw[..., 1] <= h - 1)
    values = cv2.remap(image, raw[..., 0], raw[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    values = values.astype(np.float64)
    counts = np.sum(inside, axis=0)
    levels = np.full(len(offsets), np.nan)
    full = counts == len(along_px)
    if np.any(full):
        levels[full] = np.median(values[:, full], axis=0)
    partial = ~full & (counts >= max(1, len(along_px) // 2))
    if np.any(partial):
        levels[partial] = np.nanmedian(np.where(inside[:, partial], values[:, partial], np.nan), axis=0)
    return offsets, levels


def find_steps(offsets: F64, levels: F64) -> tuple[ProfileStep, ...]:
    """Steps of a profile: lobes of one sign of its smoothed slope, with their level change and place."""
    ok = np.isfinite(levels)
    if ok.sum() < 8:
        return ()
    x, y = offsets[ok], levels[ok]
    y = cv2.GaussianBlur(y.reshape(1, -1), (0, 0), _SMOOTH_SIGMA_PX / SAMPLE_STEP_PX, borderType=cv2.BORDER_REPLICATE)[0]
    span = float(np.percentile(y, 99) - np.percentile(y, 1))
    if span <= 1e-9:
        return ()
    slope = np.diff(y)  # change per sample, between x[i] and x[i + 1]
    mid = 0.5 * (x[:-1] + x[1:])
    # Ignore the noise floor of the slope so that a flat stretch does not split or join lobes.
    floor = 3.0 * 1.4826 * float(np.median(np.abs(slope - np.median(slope))))
    sign = np.where(slope > floor, 1, np.where(slope < -floor, -1, 0))
    steps: list[ProfileStep] = []
    i = 0
    n = len(sign)
    while i < n:
        if sign[i] == 0:
            i += 1
            continue
        j = i
        while j + 1 < n and sign[j + 1] == sign[i]:
            j += 1
        s = slope[i : j + 1]
        change = float(np.sum(s))
        place = float(np.sum(s * mid[i : j + 1]) / change) if change != 0 else float(mid[(i + j) // 2])
        if abs(change) >= _MIN_STEP_FRACTION * span:
            steps.append(ProfileStep(place, change, abs(change) / span))
        i = j + 1
    return tuple(steps)


def pick_feature(steps: tuple[ProfileStep, ...], opening_darker: bool, feature: FeatureConfig) -> int | None:
    """Index in ``steps`` of the recipe's feature: the ``feature.index``-th large step of the opening's polarity."""
    wanted = [
        k
        for k, s in enumerate(steps)
        if (s.change_dn < 0) == opening_darker and s.fraction >= feature.min_step_fraction
    ]
    if feature.count_from == "opening":
        wanted.reverse()
    return wanted[feature.index] if feature.index < len(wanted) else None


def edge_profile(
    image: NDArray[np.uint8],
    lens: Lens,
    line: Line2D,
    name: str,
    along_px: F64,
    opening_darker: bool,
    feature: FeatureConfig,
) -> EdgeProfile:
    """The profile across ``line`` at places ``along_px`` (px from ``line.point``), its steps and the feature."""
    inward = into_opening(line, name)
    offsets, levels = sample_profile(image, lens, line, inward, along_px, float(feature.profile_half_px))
    steps = find_steps(offsets, levels)
    return EdgeProfile(offsets, levels, len(along_px), steps, pick_feature(steps, opening_darker, feature))
