"""The window-corner detector's settings (paper section 4.2): where to look, how, and when to refuse.

Pixel figures are full-resolution pixels of the camera image. The defaults suit the paper's cell:
a 2048 x 2048 camera at 400 mm from the wall (0.0762 mm/px), the virtual sharp corner near the
image centre and an opening corner radius of 30 mm (394 px).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from cellctl.config.arc_settings import ArcSettings
from cellctl.config.types import Finite, StrictModel


class RoiConfig(StrictModel):
    """The region of interest (raw image pixels) in which the corner and its two edges are sought.

    It must contain the corner and a straight stretch of both edges beside the arc. Left out of the
    configuration, it is the whole frame of ``layout.camera`` (:class:`cellctl.config.schema.CellConfig`).
    """

    x_px: int = Field(0, ge=0)
    y_px: int = Field(0, ge=0)
    width_px: int = Field(2048, ge=64)
    height_px: int = Field(2048, ge=64)

    def check_inside(self, image_width_px: int, image_height_px: int) -> None:
        """Raise ValueError naming the field when the ROI does not fit in an image of this size."""
        if self.x_px + self.width_px > image_width_px:
            raise ValueError(
                f"vision.roi: x_px + width_px = {self.x_px + self.width_px} exceeds the image width "
                f"{image_width_px} px; shrink width_px or move x_px"
            )
        if self.y_px + self.height_px > image_height_px:
            raise ValueError(
                f"vision.roi: y_px + height_px = {self.y_px + self.height_px} exceeds the image height "
                f"{image_height_px} px; shrink height_px or move y_px"
            )


class CoarseConfig(StrictModel):
    """Finding the two edges roughly: Canny edges and the probabilistic Hough transform.

    Both run on the ROI shrunk by ``downscale`` (area averaging), which is enough to seed the
    sub-pixel stage and keeps the frame time low; lengths and gaps are in full-resolution pixels.
    """

    downscale: Literal[1, 2, 4] = 4
    blur_sigma_px: Finite = Field(1.0, ge=0, le=10)  # Gaussian pre-blur on the shrunk image
    canny_low: Finite = Field(20.0, gt=0, le=2000)
    canny_high: Finite = Field(50.0, gt=0, le=4000)
    canny_l2_gradient: bool = True
    hough_rho_px: Finite = Field(1.0, gt=0, le=10)  # on the shrunk image
    hough_theta_deg: Finite = Field(0.5, gt=0, le=5)
    hough_threshold: int = Field(40, ge=5)  # votes, on the shrunk image
    hough_min_length_px: Finite = Field(160.0, gt=0)
    hough_max_gap_px: Finite = Field(24.0, ge=0)
    max_tilt_deg: Finite = Field(12.0, gt=0, le=40)  # an edge may lean this far from the image axes
    cluster_tolerance_px: Finite = Field(6.0, gt=0)  # segments this close belong to one line
    # The two lines of a corner must meet within this of a right angle: a mark lying across one
    # edge is not taken for the other edge unless it runs nearly parallel to it.
    max_corner_skew_deg: Finite = Field(3.0, gt=0, le=45)

    @model_validator(mode="after")
    def _order(self) -> "CoarseConfig":
        if self.canny_low >= self.canny_high:
            raise ValueError(f"canny_low ({self.canny_low:g}) must be below canny_high ({self.canny_high:g})")
        return self


class FitConfig(StrictModel):
    """Sub-pixel edge points and the line fits (RANSAC, then least squares)."""

    arc_exclusion_px: Finite = Field(440.0, ge=0)  # from the sharp corner along each edge: the arc
    border_margin_px: int = Field(12, ge=4, le=200)  # keep edge profiles this far inside the ROI
    level_samples: int = Field(2, ge=1, le=8)  # samples at each end of a profile giving its levels
    max_blur_sigma_px: Finite = Field(4.0, gt=0, le=20)  # refuse an edge blurred more than this
    ransac_iterations: int = Field(100, ge=10, le=100000)
    ransac_band_px: Finite = Field(1.0, gt=0, le=20)  # on the Canny seed points
    subpixel_band_px: Finite = Field(0.5, gt=0, le=10)  # RANSAC band on the sub-pixel points
    robust_k: Finite = Field(3.5, gt=1, le=10)  # final inliers: |residual| < k * robust sigma
    min_robust_band_px: Finite = Field(0.12, gt=0, le=5)
    # A profile is left out when the ratio of its darker to its brighter plateau leaves the edge's
    # undisturbed ratio by more than this: lighting scales both alike, light added by a glare
    # spot does not, and it biases the crossing (0.1 is a veil of about 17 DN on a 150/20 DN scene).
    background_tolerance: Finite = Field(0.1, gt=0, le=1)
    # Refuse an edge whose median normalised profile overshoots, undershoots or turns back by more
    # than this share of its contrast (or 8 sigmas of that median's noise if more): a highlight or
    # a glint beside the edge shifts the crossing (about 6 px per unit: 0.03 is 0.2 px).
    max_edge_bump: Finite = Field(0.03, gt=0, le=1)
    seed: int = Field(0, ge=0)  # RANSAC's random stream: the detector is deterministic
    check_arc: bool = True  # measure the corner arc, check both lines touch it (off for a sharp corner)


class LimitsConfig(StrictModel):
    """When the detector refuses instead of answering (each refusal names the figure and limit)."""

    min_edge_points: int = Field(100, ge=10)  # sub-pixel inliers per edge
    min_inlier_fraction: Finite = Field(0.5, gt=0, le=1)
    max_fit_rms_px: Finite = Field(0.3, gt=0)
    min_contrast_dn: Finite = Field(20.0, gt=0)  # wall minus opening, median over the edge
    perpendicular_tolerance_deg: Finite = Field(1.0, gt=0, le=45)
    max_bow_px: Finite = Field(0.25, gt=0)  # departure of an edge from a straight line
    max_corner_sigma_px: Finite = Field(0.1, gt=0)  # predicted 1-sigma of the corner from the fits
    max_saturated_fraction: Finite = Field(0.5, gt=0, le=1)  # of an edge's profiles
    # The arc check: each line must touch the circle fitted to the corner arc within this gap
    # (a line that stands off the arc would move the corner as much); the arc points must span
    # at least this angle about its centre (90 deg is the whole arc of a square corner).
    max_arc_gap_px: Finite = Field(0.3, gt=0)
    min_arc_coverage_deg: Finite = Field(30.0, ge=0, le=90)
    # |fitted arc radius / expected - 1|, the expected radius being the recipe's
    # layout.opening.corner_radius_mm in px: a circle tangent to a second edge beside the true one
    # (a shadow or sealant band) is far larger (35 % for a 60 px band at a 200 px radius); a good
    # image's arc is within 0.3 %, the rest is left for the body's tolerance and the shooting distance.
    arc_radius_tolerance: Finite = Field(0.1, gt=0, le=0.5)


class FeatureConfig(StrictModel):
    """Which edge of the opening's profile is the feature the corner is measured on.

    A real opening shows several edges parallel to each other (a paint edge, the wall's edge, a
    flange, a seal's inner edge). Across each straight edge the detector takes the median profile
    of many cross-sections (a mark or a dirt spot crossing a few of them does not move it), finds
    its steps, and keeps those of the opening's polarity (``opening_polarity``: a darker opening
    means steps that fall towards it) whose size is at least ``min_step_fraction`` of the
    profile's whole wall-to-opening range. The feature is the step ``index`` (0 the first) counted
    from ``count_from``: "wall" (outside in) or "opening" (inside out). The default, the first
    strong falling step from the wall, is the wall's own edge; a seal's inner edge is the first
    step from the opening with a lower ``min_step_fraction``. Teaching checks the rule on the
    template image and records the step it picks and the profile's steps, which each shot's
    profile is checked against (``taught_profile``).
    """

    count_from: Literal["wall", "opening"] = "wall"
    index: int = Field(0, ge=0, le=5)
    min_step_fraction: Finite = Field(0.25, gt=0, lt=1)
    # Half-length of the cross-sections, either side of the coarse line (px): it must reach past
    # every band the rule counts (the default covers 30 mm at 0.0762 mm/px).
    profile_half_px: int = Field(400, ge=20, le=1000)
    # Cross-sections taken along each straight edge, and along an arc (their median is the profile).
    cross_sections: int = Field(24, ge=8, le=400)
    # Check each shot's profile against the one teaching recorded (cellctl.vision.taught_profile): the
    # feature is the one step whose neighbours of the opening's polarity (those the rule counts, and
    # fainter ones within taught_near_px) lie as taught within taught_place_px (px at the fixed
    # shooting scale); otherwise the shot is refused. False: the rule alone counts, as for a
    # calibration set taught before profiles were recorded. taught_near_px stays below the nearest
    # band whose width varies from body to body (the twin's flange: 4 mm, 52 px, at least).
    taught_profile: bool = True
    taught_place_px: Finite = Field(5.0, gt=0, le=50)
    taught_near_px: Finite = Field(48.0, ge=0, le=1000)


class GapVisionConfig(StrictModel):
    """The post-install inspection image: the opening's and the glass's edges at the corner (cellctl.vision.gap).

    At the shooting pose the opening's corner lies within a few pixels of the template. Along the
    straight part of the top and the right edge (from ``start_px`` beyond the corner, leaving the
    arc out, for ``length_px``), the median profile across each edge gives the opening's edge (the
    recipe's feature, ``[vision.feature]``, within ``opening_search_px`` of the template's line)
    and the glass's edge (the strongest step within ``glass_search_px`` of where the nominal gap
    puts it); with ``frit_edge`` the glass must show its frit's inner border beyond it (a step back
    towards the clear glass: an empty opening has none). Each edge is then measured to sub-pixel
    on every pixel column or row and fitted with a robust line; a fit is refused below
    ``min_points`` inliers, above ``max_rms_px`` or ``max_bow_px``, or under ``min_contrast_dn``.
    """

    start_px: Finite = Field(440.0, ge=0)  # from the virtual corner along each edge: past the arc
    length_px: Finite = Field(560.0, ge=50)  # the window measured along each edge (cut at the image border)
    border_margin_px: int = Field(12, ge=4, le=200)
    opening_search_px: Finite = Field(25.0, gt=0, le=300)  # opening's edge from the template's line
    glass_search_px: Finite = Field(20.0, gt=0, le=300)  # glass's edge from the nominal gap
    min_step_fraction: Finite = Field(0.06, gt=0, lt=1)  # the glass's and the frit's steps, of the profile's range
    frit_edge: bool = True  # require the frit's inner border beyond the glass's edge (no glass: refused)
    frit_search_px: Finite = Field(700.0, gt=0, le=2000)  # how far beyond the glass's edge it may lie
    cross_sections: int = Field(24, ge=8, le=400)  # cross-sections whose median is each edge's profile
    max_blur_sigma_px: Finite = Field(2.5, gt=0, le=10)  # sizes the sub-pixel windows (they must not reach the other edge)
    min_points: int = Field(150, ge=10)  # sub-pixel inliers per edge
    max_rms_px: Finite = Field(0.6, gt=0)  # scatter about the line (noise: 0.35 px on a 30 DN glass edge)
    max_bow_px: Finite = Field(0.25, gt=0)
    min_contrast_dn: Finite = Field(10.0, gt=0)  # across each edge, median over its profiles
    ransac_band_px: Finite = Field(0.5, gt=0, le=10)
    robust_k: Finite = Field(3.5, gt=1, le=10)
    max_edge_bump: Finite = Field(0.06, gt=0, le=1)  # as vision.fit.max_edge_bump; the glass's edge is fainter and less clean
    seed: int = Field(0, ge=0)  # RANSAC's random stream: the measurement is deterministic


class VisionConfig(StrictModel):
    """Corner detection of paper section 4.2: ROI, coarse search, fits and refusal limits.

    ``opening_polarity`` says whether the opening looks darker or brighter than the wall; "auto"
    accepts either as long as both edges agree.
    """

    roi: RoiConfig = RoiConfig()
    coarse: CoarseConfig = CoarseConfig()
    fit: FitConfig = FitConfig()
    limits: LimitsConfig = LimitsConfig()
    opening_polarity: Literal["darker", "brighter", "auto"] = "darker"
    feature: FeatureConfig = FeatureConfig()
    gap: GapVisionConfig = GapVisionConfig()  # the post-install inspection image (issue 16)
    arc: ArcSettings = ArcSettings()  # the arc corner, where the recipe's radius needs it (issue 21)
    # The point of the opening's plane, in T's x and y (mm), on the camera's axis at the shooting
    # pose. None: the virtual corner for the corner method; for the arc, the place that keeps the
    # arc and the top edge's straight run in view (cellctl.config.feature).
    shot_aim_mm: tuple[Finite, Finite] | None = None
