"""The shot's feature for eq. 16: the sharp corner of two straight edges (paper 4.2), or the arc's
centre where the recipe's corner radius leaves the straight edges out of view (issue 21).

Both answers become :class:`~cellctl.vision.corner.CornerFeatures` (u, v, theta and the edges'
angles, NaN for an edge not seen), so teaching, the nine-point map and the offset treat them alike;
where the feature lies in T is the recipe's (cellctl.config.feature.feature_point_mm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cellctl.config.arc_vision import ArcCornerConfig
from cellctl.config.feature import CornerRadius
from cellctl.config.vision import VisionConfig
from cellctl.vision.arc_corner import ArcCornerMeasurement, detect_arc_corner
from cellctl.vision.corner import CornerFeatures, CornerMeasurement, detect_corner
from cellctl.vision.lens import Lens
from cellctl.vision.quality import Refusal
from cellctl.vision.taught_profile import TaughtProfile

__all__ = ["FeatureShot", "detect_feature"]


@dataclass(frozen=True)
class FeatureShot:
    """One image's feature: eq. 16's figures with their 1-sigma (px), or the refusal and why."""

    measurement: CornerMeasurement | ArcCornerMeasurement
    features: CornerFeatures | None
    sigma_px: float | None
    refusal: Refusal | None
    message: str

    @property
    def ok(self) -> bool:
        return self.refusal is None

    @property
    def kind(self) -> str:
        return "arc" if isinstance(self.measurement, ArcCornerMeasurement) else "corner"


def _arc_features(m: ArcCornerMeasurement) -> CornerFeatures | None:
    o = m.orientation
    if m.centre_px is None or o is None or o.theta_rad is None:
        return None
    top = o.top.angle_rad if o.top is not None and o.top.ok else np.nan
    right = o.right.angle_rad if o.right is not None and o.right.ok else np.nan
    return CornerFeatures(float(m.centre_px[0]), float(m.centre_px[1]), float(o.theta_rad), float(top), float(right))


# The first shot only aims the verification shots: the arc may be cut by the car body's placement.
FIRST_SHOT_MIN_COVERAGE_DEG = 20.0
FIRST_SHOT_ARC_SIGMA_FACTOR = 2.0  # of the corner's first-shot sigma: a short arc's centre is looser, and only aims


def first_shot_limits(
    vision: VisionConfig, arc: ArcCornerConfig | None, sigma_px: float, min_edge_points: int
) -> tuple[VisionConfig, ArcCornerConfig | None]:
    """The detectors' limits for the first shot: a looser sigma (and edge points, or arc coverage)."""
    limits = vision.limits.model_copy(update={"max_corner_sigma_px": sigma_px, "min_edge_points": min_edge_points})
    if arc is not None:
        arc_limits = arc.limits.model_copy(
            update={"max_centre_sigma_px": max(FIRST_SHOT_ARC_SIGMA_FACTOR * sigma_px, arc.limits.max_centre_sigma_px),
                    "min_coverage_deg": min(FIRST_SHOT_MIN_COVERAGE_DEG, arc.limits.min_coverage_deg)}
        )  # fmt: skip
        arc = arc.model_copy(update={"limits": arc_limits})
    return vision.model_copy(update={"limits": limits}), arc


def detect_feature(
    image: NDArray[np.uint8],
    lens: Lens,
    vision: VisionConfig,
    arc: ArcCornerConfig | None,
    *,
    need_orientation: bool = True,
    corner_radius: CornerRadius | None = None,
    taught: TaughtProfile | None = None,
) -> FeatureShot:
    """The corner (``arc`` None) or the arc's centre with the top edge's orientation in a raw image.

    ``corner_radius`` (the recipe's ShotFeature.corner_radius) is the radius the corner's arc check expects;
    ``taught`` the corner's taught profiles, its edges' features are checked against (the arc's are not).

    Without ``need_orientation`` an arc seen without a straight edge still answers, its angles NaN
    (the offset then turns by 0: a first shot that only aims the next).
    """
    if arc is None:
        m = detect_corner(image, lens, vision, corner_radius, taught)
        return FeatureShot(m, m.features if m.ok else None, m.corner_sigma_px, m.refusal, m.message)
    a = detect_arc_corner(image, lens, arc)
    if not a.ok:
        return FeatureShot(a, None, a.centre_sigma_px, a.refusal, a.message)
    features = _arc_features(a)
    if features is None and not need_orientation:
        assert a.centre_px is not None
        nan = float("nan")
        return FeatureShot(a, CornerFeatures(float(a.centre_px[0]), float(a.centre_px[1]), nan, nan, nan), a.centre_sigma_px,
                           None, a.message + " (no orientation: it turns nothing)")  # fmt: skip
    if features is None:
        why = a.orientation.reason if a.orientation is not None else "no orientation"
        return FeatureShot(a, None, a.centre_sigma_px, Refusal.ARC_NOT_SEEN, f"refused: the arc's orientation: {why}")
    return FeatureShot(a, features, a.centre_sigma_px, None, a.message)
