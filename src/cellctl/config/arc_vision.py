"""The large-radius corner's settings (issue 21): the arc itself is the feature (cellctl.vision.arc_corner).

With a corner radius of 100-200 mm the straight edges lie outside the 156 mm view, so the paper's
alternative applies: fit the arc, take its centre as the feature point and derive the lines from
its centre, radius and tangent directions. Pixel figures are full-resolution pixels of the camera
image; the defaults suit the paper's cell (2048 x 2048 at 0.0762 mm/px, a 150 mm radius: 1969 px).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from cellctl.config.arc_settings import ArcLimitsConfig, ArcSearchConfig, ArcSettings, ArcTangentConfig
from cellctl.config.types import Finite, StrictModel
from cellctl.config.vision import FeatureConfig, RoiConfig

__all__ = ["ArcCornerConfig", "ArcLimitsConfig", "ArcSearchConfig", "ArcSettings", "ArcTangentConfig"]


class ArcCornerConfig(StrictModel):
    """The arc corner detector: expected radius (px), ROI, search, refusal limits, tangent edges.

    ``feature`` picks the arc among the opening's concentric ones (paint edge, wall's edge,
    flange, seal) by the same rule as the straight edges' (cellctl.vision.arc_profile).
    """

    expected_radius_px: Finite = Field(1969.0, gt=10)  # the recipe's radius over the pixel scale
    roi: RoiConfig = RoiConfig()
    opening_polarity: Literal["darker", "brighter"] = "darker"
    search: ArcSearchConfig = ArcSearchConfig()
    limits: ArcLimitsConfig = ArcLimitsConfig()
    tangent: ArcTangentConfig = ArcTangentConfig()
    feature: FeatureConfig = FeatureConfig()
