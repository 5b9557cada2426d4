"""Sub-pixel edge positions along short profiles across an edge (the "area" estimator).

Each profile is a line of pixels across the edge, along an image row or column. With the profile
normalised to 0 on one plateau and 1 on the other, the sum of the normalised samples equals the
length of the window beyond the edge: a blurred step edge, integrated over the pixels or sampled
at their centres, carries exactly its share of area whatever the blur and wherever the edge falls
between pixel centres. So the estimate has no sub-pixel phase bias, unlike the parabola peak of
the gradient (up to about 0.05 px at 0.8 px blur) or a linearly interpolated 50 % crossing (about
0.02 px): a bias of that kind does not average out along an edge that runs along the pixel grid.

The window is resampled (linear interpolation along the profile) to be symmetric about a first
estimate, and the two levels are the means of its first and last samples; a slowly varying
background (uneven lighting, a glare veil) then cancels to first order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

# Re-centring stops when 90 % of the crossings move less than this (a background slope g DN/px
# leaves a bias of about g * window / contrast times the last step; noise keeps a few profiles
# moving by more, harmlessly).
_CENTRING_TOLERANCE_PX = 0.002
_MAX_RECENTRING = 4


@dataclass(frozen=True)
class EdgeCrossings:
    """Edge crossings measured on a set of profiles.

    ``position`` is the crossing's coordinate along the profile axis (raw pixels), ``contrast``
    the level after the edge minus the level before it (in the direction of growing coordinate;
    ``level_before``/``level_after`` are those plateau levels),
    ``blur_sigma_px`` the edge's Gaussian-equivalent spread (pixel footprint included; it reads
    up to 15 % high below 1 px of blur, and high on a sloping background), ``valid`` whether the profile gave
    a crossing inside its window with both plateaus inside the image and nothing else in the
    window (a mark or a spot crossing it: see ``_foreign``), ``saturated`` whether a sample reached
    the sensor's top value. ``normalised`` holds each profile's final window scaled to 0 and 1 on
    its plateaus and centred on its crossing (rows align: their median is the edge's mean shape).
    """

    position: F64
    contrast: F64
    blur_sigma_px: F64
    valid: NDArray[np.bool_]
    saturated: NDArray[np.bool_]
    level_before: F64
    level_after: F64
    normalised: F64 = field(default_factory=lambda: np.zeros((0, 0)))

    @classmethod
    def empty(cls) -> "EdgeCrossings":
        """No profiles at all."""
        z = np.zeros(0)
        return cls(z, z, z, np.zeros(0, bool), np.zeros(0, bool), z, z)


def _sample_profiles(
    image: NDArray[np.generic], fixed: NDArray[np.int64], centre: F64, half: int, along_rows: bool
) -> tuple[F64, NDArray[np.bool_], NDArray[np.bool_]]:
    """Profile values at centre + j (j = -half..half), linearly interpolated along the profile axis.

    ``along_rows`` False: the profile runs along v at column ``fixed``; True: along u at row ``fixed``.
    Returns (values (N, 2 half + 1), inside mask (N,), saturated mask (N,)).
    """
    size = image.shape[1] if along_rows else image.shape[0]
    base = np.floor(centre).astype(np.int64)
    frac = centre - base
    j = np.arange(-half, half + 2, dtype=np.int64)
    idx = base[:, None] + j[None, :]
    inside = (idx[:, 0] >= 0) & (idx[:, -1] <= size - 1)
    idx = np.clip(idx, 0, size - 1)
    if along_rows:
        raw = image[fixed[:, None], idx]
    else:
        raw = image[idx, fixed[:, None]]
    raw = raw.astype(np.float64)
    top = float(np.iinfo(image.dtype).max) if np.issubdtype(image.dtype, np.integer) else np.inf
    saturated = np.any(raw >= top, axis=1)
    values = raw[:, :-1] * (1.0 - frac[:, None]) + raw[:, 1:] * frac[:, None]
    return values, inside, saturated


def _foreign(values: F64, lo: F64, contrast: F64, level_samples: int) -> NDArray[np.bool_]:
    """Profiles whose window holds something besides the one blurred step: a mark, a spot, another edge.

    A blurred step normalised to 0 and 1 on its plateaus rises monotonically within [0, 1] but
    for noise; a line or a spot in the window either leaves that range or turns the profile back
    by its own contrast. The allowance is a quarter of the step, or five sigmas of the plateaus' noise
    (estimated over all profiles) if that is larger, so a faint edge is not thinned out by noise.
    """
    m = level_samples
    plateau = np.concatenate([values[:, :m] - values[:, :m].mean(axis=1, keepdims=True),
                              values[:, -m:] - values[:, -m:].mean(axis=1, keepdims=True)], axis=1)
    noise_dn = 1.4826 * float(np.median(np.abs(plateau))) * np.sqrt(m / max(m - 1, 1)) if m > 1 else 0.0
    safe = np.where(np.abs(contrast) > 1e-9, contrast, 1e-9)
    f = (values - lo[:, None]) / safe[:, None]
    allowance = np.maximum(0.25, 5.0 * noise_dn / np.abs(safe))
    # A blurred step never turns back; noise does, by up to the spread of its extremes in a window.
    dip = np.max(np.maximum.accumulate(f, axis=1) - f, axis=1)
    dip_allowance = np.maximum(0.25, 7.0 * noise_dn / np.abs(safe))
    return (f.min(axis=1) < -allowance) | (f.max(axis=1) > 1.0 + allowance) | (dip > dip_allowance)


def _area_estimate(values: F64, centre: F64, half: int, level_samples: int) -> tuple[F64, F64, F64, F64]:
    """Crossing position, level before, contrast and spread from profiles sampled at centre + j, j = -half..half."""
    m = level_samples
    lo = values[:, :m].mean(axis=1)
    hi = values[:, -m:].mean(axis=1)
    contrast = hi - lo
    safe = np.where(np.abs(contrast) > 1e-9, contrast, 1e-9)
    f = (values - lo[:, None]) / safe[:, None]
    position = centre + half + 0.5 - f.sum(axis=1)
    # Spread: for a Gaussian-blurred step the integral of f (1 - f) is sigma / sqrt(pi); plateau
    # noise adds nothing to it on average (unlike a second moment of the slope).
    var = (np.sqrt(np.pi) * np.sum(f * (1.0 - f), axis=1)) ** 2 - 1.0 / 12.0
    return position, lo, contrast, np.sqrt(np.clip(var, 0.0, None))


def measure_crossings(
    image: NDArray[np.generic],
    fixed: NDArray[np.int64],
    expected: F64,
    *,
    along_rows: bool,
    search_px: float,
    level_samples: int,
    max_blur_sigma_px: float,
) -> EdgeCrossings:
    """Edge crossings near ``expected`` on profiles at rows/columns ``fixed``.

    Pass 1 uses a window wide enough for the expected position's uncertainty ``search_px`` and
    the largest blur accepted; pass 2 re-centres a window sized to the measured blur (its median
    over the profiles) on the pass 1 result, and is re-centred until the crossings stop moving.
    """
    fixed = np.asarray(fixed, dtype=np.int64)
    expected = np.asarray(expected, dtype=np.float64)
    m = level_samples
    half1 = int(np.ceil(search_px + 3.0 * max_blur_sigma_px)) + m
    values, inside, saturated = _sample_profiles(image, fixed, expected, half1, along_rows)
    pos, lo, contrast, spread = _area_estimate(values, expected, half1, m)
    ok = inside & np.isfinite(pos) & (np.abs(pos - expected) <= half1 - m - 0.5)
    sigma = float(np.median(spread[ok])) if np.any(ok) else max_blur_sigma_px
    sigma = float(np.clip(sigma, 0.3, max_blur_sigma_px))
    half2 = int(np.ceil(3.0 * sigma + 1.0)) + m
    centre = np.where(ok, pos, expected)
    for _ in range(_MAX_RECENTRING):
        values, inside2, sat2 = _sample_profiles(image, fixed, centre, half2, along_rows)
        pos2, lo, contrast, spread = _area_estimate(values, centre, half2, m)
        inside = inside & inside2
        saturated = saturated | sat2
        ok = ok & inside & np.isfinite(pos2) & (np.abs(pos2 - centre) <= half2 - m - 0.5)
        step = np.abs(pos2 - centre)
        centre = np.where(ok, pos2, centre)
        if not np.any(ok) or float(np.percentile(step[ok], 90)) < _CENTRING_TOLERANCE_PX:
            break
    ok &= ~_foreign(values, lo, contrast, m)
    safe = np.where(np.abs(contrast) > 1e-9, contrast, 1e-9)
    normalised = (values - lo[:, None]) / safe[:, None]
    return EdgeCrossings(centre, contrast, spread, ok, saturated, lo, lo + contrast, normalised)


def shape_bump(normalised: F64, level_samples: int) -> tuple[float, float]:
    """How far the median normalised profile strays from one monotonic step, and that median's noise (contrast shares).

    A blurred step rises from 0 to 1 without overshoot or dip; a highlight or a glint beside the
    edge adds a bump the area estimator takes for a shift of the edge. The median over many
    profiles shows it though each profile's noise would hide it; its own noise is taken from the
    plateau samples (as in ``_foreign``), over the square root of the number of profiles.
    """
    n, m = normalised.shape[0], level_samples
    if n == 0 or normalised.shape[1] < 2 * m:
        return 0.0, 0.0
    med = np.median(normalised, axis=0)
    dip = float(np.max(np.maximum.accumulate(med) - med))
    bump = max(float(med.max()) - 1.0, -float(med.min()), dip)
    ends = (normalised[:, :m], normalised[:, -m:])
    plateau = np.concatenate([e - e.mean(axis=1, keepdims=True) for e in ends], axis=1)
    sample_noise = 1.4826 * float(np.median(np.abs(plateau))) * np.sqrt(m / max(m - 1, 1)) if m > 1 else 0.0
    return bump, 1.2533 * sample_noise / np.sqrt(n)
