"""The inspection image's profiles: where the opening's and the glass's edges lie across each edge (issue 16).

See cellctl.vision.gap (steps 1 to 3): the median profile across the template's line, its steps
(cellctl.vision.profile), the recipe's feature edge among those outside the glass's search window,
the glass's edge near the nominal gap, and the frit's inner border that tells a glass from an
empty opening.
"""

from __future__ import annotations

from enum import Enum

import numpy as np
from numpy.typing import NDArray

from cellctl.config.vision import FeatureConfig, GapVisionConfig
from cellctl.vision.edge import EdgeName
from cellctl.vision.lens import Lens
from cellctl.vision.lines import Line2D
from cellctl.vision.profile import EdgeProfile, ProfileStep, find_steps, into_opening, pick_feature, sample_profile
from cellctl.vision.quality import Refused

F64 = NDArray[np.float64]


class GapRefusal(str, Enum):
    """Why the inspection image gives no gaps."""

    NO_GLASS = "no_glass"  # no glass's edge with its frit border where a glass should be
    OPENING_EDGE_NOT_FOUND = "opening_edge_not_found"  # the recipe's feature edge not near the template
    GLASS_EDGE_NOT_FOUND = "glass_edge_not_found"  # a glass, but its edge outside the search window
    EDGE_MISSING = "edge_missing"  # an edge's straight part not in the image, or too few points
    LOW_CONTRAST = "low_contrast"
    SATURATED = "saturated"
    POOR_FIT = "poor_fit"
    EDGE_BENT = "edge_bent"


def steps_text(steps: tuple[ProfileStep, ...] | list[ProfileStep]) -> str:
    return ", ".join(f"{s.offset_px:+.0f} px {s.change_dn:+.0f} DN ({s.fraction:.2f})" for s in steps) or "none"


class GapRefused(Refused[GapRefusal]):
    """An inspection refusal (turned into a GapMeasurement)."""


def find_gap_steps(
    image: NDArray[np.uint8], lens: Lens, name: EdgeName, line: Line2D, along: F64, config: GapVisionConfig,
    feature: FeatureConfig, opening_darker: bool | None, gap_px: float,
) -> tuple[EdgeProfile, ProfileStep, ProfileStep]:
    """The profile across one edge and on it the opening's edge and the glass's edge (module docstring, 1-3).

    ``opening_darker`` None takes the polarity of the strongest step near the template's line.
    """
    inward = gap_px + config.glass_search_px + config.frit_search_px
    half = float(np.ceil(max(feature.profile_half_px, inward)))
    places = np.linspace(along[0], along[-1], config.cross_sections)
    offsets, levels = sample_profile(image, lens, line, into_opening(line, name), places, half)
    levels = np.where(offsets < -feature.profile_half_px, np.nan, levels)  # the wall as the corner detector sees it
    steps = find_steps(offsets, levels)
    profile = EdgeProfile(offsets, levels, len(places), steps, None)
    lo_glass = gap_px - config.glass_search_px
    outside = [s for s in steps if s.offset_px < lo_glass]
    if opening_darker is None:
        near = [s for s in outside if abs(s.offset_px) <= config.opening_search_px]
        opening_darker = max(near, key=lambda s: abs(s.change_dn)).change_dn < 0.0 if near else True
    k = pick_feature(tuple(outside), opening_darker, feature)
    if k is None:
        raise GapRefused(
            GapRefusal.OPENING_EDGE_NOT_FOUND,
            f"the {name} edge: the recipe's feature edge (step {feature.index} from the {feature.count_from}, at least "
            f"{feature.min_step_fraction:g} of the range) is not on its profile outside the glass; steps found "
            f"(place from the template's line into the opening, change, share of the range): {steps_text(steps)}",
        )
    opening = outside[k]
    if abs(opening.offset_px) > config.opening_search_px:
        raise GapRefused(
            GapRefusal.OPENING_EDGE_NOT_FOUND,
            f"the {name} edge: the recipe's feature edge lies {opening.offset_px:+.1f} px from the template's line, "
            f"beyond opening_search_px = {config.opening_search_px:g} (not at the shooting pose, or the taught edge "
            f"is hidden under the glass); steps found: {steps_text(steps)}",
        )
    expected = opening.offset_px + gap_px
    minimum = config.min_step_fraction
    window = [s for s in steps if abs(s.offset_px - expected) <= config.glass_search_px and s.fraction >= minimum]
    glass = max(window, key=lambda s: abs(s.change_dn)) if window else None
    beyond_from = glass.offset_px if glass is not None else opening.offset_px
    back = 1.0 if opening_darker else -1.0  # against the opening's polarity: the frit's border to the clear glass
    frit = [
        s for s in steps
        if beyond_from + 3.0 < s.offset_px <= beyond_from + config.frit_search_px and s.fraction >= minimum
        and np.sign(s.change_dn) == back
    ]
    if config.frit_edge and not frit:
        raise GapRefused(
            GapRefusal.NO_GLASS,
            f"no glass in the opening: beyond the {name} edge no step turns back against the opening's polarity (the "
            f"inner border of a glass's frit band) within {config.frit_search_px:g} px; steps found: {steps_text(steps)}",
        )
    if glass is None:
        raise GapRefused(
            GapRefusal.GLASS_EDGE_NOT_FOUND,
            f"the glass's {name} edge is not within glass_search_px = {config.glass_search_px:g} of where the nominal "
            f"gap puts it ({expected:+.1f} px from the template's line, {gap_px:.1f} px inside the opening's edge); "
            f"steps found: {steps_text(steps)}",
        )
    return profile, opening, glass
