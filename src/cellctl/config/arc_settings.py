"""The large-radius corner detector's tuning (issue 21): search, refusal limits, tangent edges.

A recipe sets them as ``[vision.arc]`` (:class:`ArcSettings`); the detector's whole input,
with the expected radius, ROI, polarity and feature rule the recipe's geometry and vision give,
is :class:`cellctl.config.arc_vision.ArcCornerConfig`. Pixel figures are full-resolution pixels.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from cellctl.config.types import Finite, StrictModel


class ArcSearchConfig(StrictModel):
    """Finding the arc and measuring it: Canny, a centre vote, RANSAC, sub-pixel profiles, robust fit.

    Canny runs on the ROI shrunk by ``downscale``; each edge pixel votes for the centre one
    expected radius behind it (its gradient direction), and a RANSAC circle through the pixels
    of the strongest vote seeds the sub-pixel stage (every pixel row or column across the arc).
    """

    downscale: Literal[1, 2, 4] = 4
    blur_sigma_px: Finite = Field(1.0, ge=0, le=10)  # Gaussian pre-blur on the shrunk image
    canny_low: Finite = Field(20.0, gt=0, le=2000)
    canny_high: Finite = Field(50.0, gt=0, le=4000)
    vote_bin_fraction: Finite = Field(0.05, gt=0, le=0.5)  # centre-vote bin, of the expected radius
    ransac_iterations: int = Field(300, ge=10, le=100000)
    ransac_band_px: Finite = Field(1.5, gt=0, le=20)  # on the Canny pixels, times ``downscale``
    border_margin_px: int = Field(12, ge=4, le=200)  # keep profiles this far inside the ROI
    level_samples: int = Field(2, ge=1, le=8)
    max_blur_sigma_px: Finite = Field(4.0, gt=0, le=20)
    robust_k: Finite = Field(3.5, gt=1, le=10)  # final inliers: |residual| < k * robust sigma
    min_robust_band_px: Finite = Field(0.15, gt=0, le=5)
    background_tolerance: Finite = Field(0.1, gt=0, le=1)  # plateau ratio off the arc's own (glare)
    seed: int = Field(0, ge=0)  # RANSAC's random stream: the detector is deterministic


class ArcLimitsConfig(StrictModel):
    """When the arc detector refuses instead of answering (each refusal names the figure and limit)."""

    radius_tolerance: Finite = Field(0.05, gt=0, le=0.5)  # |R - expected| / expected
    min_points: int = Field(200, ge=10)  # sub-pixel inliers on the arc
    min_coverage_deg: Finite = Field(40.0, gt=0, le=180)  # angle the inliers span about the centre
    max_rms_px: Finite = Field(0.3, gt=0)
    min_contrast_dn: Finite = Field(20.0, gt=0)
    max_saturated_fraction: Finite = Field(0.5, gt=0, le=1)
    # "One circle": within the inliers' span, the share of profiles that are inliers, the longest
    # stretch of arc without one (an occluder's border or a glare veil cuts the arc), and the
    # share of profiles left out for an uneven background (glare).
    min_inlier_fraction: Finite = Field(0.9, gt=0, le=1)
    max_gap_px: Finite = Field(15.0, gt=0)
    max_uneven_fraction: Finite = Field(0.1, ge=0, le=1)
    max_centre_sigma_px: Finite = Field(0.2, gt=0)  # predicted 1-sigma of the centre from the fit (0.015 mm)


class ArcTangentConfig(StrictModel):
    """The orientation from the straight edges beyond the arc's ends, where they are in view."""

    start_px: Finite = Field(5.0, ge=0)  # from the tangent point outwards: the arc left out
    min_length_px: Finite = Field(80.0, gt=0)  # straight run needed for an orientation
    min_points: int = Field(50, ge=10)
    # An edge may lean this far from the image axes; the arc is profiled only within as much of its quarter
    # (up to right): past its tangent points the circle runs beside the straight edges, over the inner bands'.
    max_tilt_deg: Finite = Field(5.0, gt=0, le=30)
    max_tangent_gap_px: Finite = Field(0.5, gt=0)  # |distance of the centre from the line - R|
    # The edge's angle from the arc and the edge fitted as one outline only where its own line stands
    # within this of the arc (else from its own line): a standoff turns the joint fit by about 0.13 deg
    # per px on the door window (1970 px radius, 425 px of edge; 0.1 px: 0.013 deg); 0: never joint.
    joint_fit_max_gap_px: Finite = Field(0.1, ge=0)
    max_rms_px: Finite = Field(0.3, gt=0)
    max_angle_sigma_deg: Finite = Field(0.05, gt=0)  # predicted 1-sigma of an edge's angle
    perpendicular_tolerance_deg: Finite = Field(1.0, gt=0, le=45)  # when both edges are seen


class ArcSettings(StrictModel):
    """``[vision.arc]``: how the arc corner is found and when it is refused (a recipe's large radius)."""

    search: ArcSearchConfig = ArcSearchConfig()
    limits: ArcLimitsConfig = ArcLimitsConfig()
    tangent: ArcTangentConfig = ArcTangentConfig()
