"""The post-install inspection image: the opening's and the glass's edges at the corner (issue 16).

After the install the robot backs off to the shooting pose, so the opening's corner lies within a
few pixels of the taught template (u_d, v_d, theta_d). From the template, for the top and the
right edge:

1. Profile (cellctl.vision.profile): the median of ``cross_sections`` cross-sections across the
   template's line, taken along the edge's straight part (``start_px`` beyond the virtual corner,
   past the arc, for ``length_px``), and its steps.
2. The opening's edge: the recipe's feature step (``[vision.feature]``, as the corner detector
   picks it) among the steps outside the glass's search window; it must lie within
   ``opening_search_px`` of the template's line (a feature hidden under the glass is refused).
3. The glass's edge: the strongest step within ``glass_search_px`` of where the nominal gap
   (``gap_px_expected``) puts it, inwards of the opening's edge. With ``frit_edge``, the glass
   must show its dark frit band's inner border beyond it, a step against the opening's polarity
   (brighter again, for an opening darker than the wall: an empty opening's flange, seal and
   interior only ever darken towards the interior): otherwise there is no glass in the image.
4. Sub-pixel lines (cellctl.vision.edge): each of the four edges is measured on every pixel column
   (top) or row (right) of its window by the area estimator, undistorted by the lens and fitted by
   RANSAC and a robust least-squares refit, held to the limits of :class:`GapVisionConfig`.

Pure: arrays in, a :class:`GapMeasurement` out (a refusal with its reason when an edge is missing
or fails its limits). The figures in millimetres (gaps, the glass's offset, parallax) are
:func:`cellctl.vision.gap_figures.in_plane_from_gaps`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cellctl.config.vision import FeatureConfig, FitConfig, GapVisionConfig, LimitsConfig, RoiConfig, VisionConfig
from cellctl.vision.corner import CornerFeatures
from cellctl.vision.edge import AWAY, INSPECTION_SETTINGS, EdgeMeasurement, EdgeName, measure_edge
from cellctl.vision.lens import Lens
from cellctl.vision.lines import Line2D, intersect
from cellctl.vision.gap_figures import GapLines, InPlaneGaps, in_plane_from_gaps
from cellctl.vision.gap_steps import GapRefusal, GapRefused, find_gap_steps
from cellctl.vision.profile import EdgeProfile, ProfileStep, into_opening
from cellctl.vision.quality import Check, Refused
from cellctl.vision.taught_profile import TaughtProfile, match_taught, rule_problem

__all__ = ["GapLines", "GapMeasurement", "GapRefusal", "InPlaneGaps", "in_plane_from_gaps", "measure_gaps", "template_lines"]

F64 = NDArray[np.float64]
EDGE_NAMES: tuple[EdgeName, EdgeName] = ("top", "right")

# The profile's steps place an edge to about a pixel; the sub-pixel stage searches this far about it.
SUBPIXEL_SEARCH_PX = 3.0


@dataclass(frozen=True)
class GapMeasurement:
    """The inspection image's answer: four edges with their quality, or a refusal with its reason.

    ``opening_*``/``glass_*`` are the sub-pixel edges (lines in the ideal image, points, inliers,
    RMS, contrast; see :class:`cellctl.vision.edge.EdgeMeasurement`), kept as far as they were
    measured when refused. ``profiles`` are the median profiles across the top and right edges
    (offsets from the template's line, positive into the opening); ``steps_px`` the places on them
    of the opening's and the glass's edges. ``start_px`` is where the measured straight parts
    begin, along each edge from the opening's virtual corner.
    """

    refusal: GapRefusal | None
    message: str
    start_px: float
    opening_top: EdgeMeasurement | None = None
    opening_right: EdgeMeasurement | None = None
    glass_top: EdgeMeasurement | None = None
    glass_right: EdgeMeasurement | None = None
    profiles: dict[str, EdgeProfile] | None = None
    steps_px: dict[str, tuple[float, float]] | None = None
    checks: tuple[Check, ...] = ()

    @property
    def ok(self) -> bool:
        return self.refusal is None

    @property
    def lines(self) -> GapLines:
        """The four lines; raises ValueError when the measurement was refused."""
        edges = (self.opening_top, self.opening_right, self.glass_top, self.glass_right)
        if self.refusal is not None or any(e is None for e in edges):
            raise ValueError(f"no gap lines: the measurement was refused ({self.message})")
        ot, orr, gt, gr = (e.line for e in edges if e is not None)
        return GapLines(ot, orr, gt, gr)

    @property
    def opening_corner_px(self) -> F64 | None:
        """The opening's virtual corner (its lines' intersection) in the ideal image, if both are measured."""
        if self.opening_top is None or self.opening_right is None:
            return None
        return intersect(self.opening_top.line, self.opening_right.line)

    @property
    def glass_corner_px(self) -> F64 | None:
        """The glass's tangent corner (its lines' intersection) in the ideal image, if both are measured."""
        if self.glass_top is None or self.glass_right is None:
            return None
        return intersect(self.glass_top.line, self.glass_right.line)

    def _edges(self) -> dict[str, EdgeMeasurement]:
        named = {"opening_top": self.opening_top, "opening_right": self.opening_right,
                 "glass_top": self.glass_top, "glass_right": self.glass_right}
        return {k: e for k, e in named.items() if e is not None}

    @property
    def points(self) -> dict[str, int]:
        """Inlier points per measured edge."""
        return {k: e.quality.inliers for k, e in self._edges().items()}

    @property
    def rms_px(self) -> dict[str, float]:
        """RMS residual (px) of each measured edge's inliers about its line."""
        return {k: e.quality.rms_px for k, e in self._edges().items()}


def template_lines(template: CornerFeatures) -> dict[EdgeName, Line2D]:
    """The taught corner's two lines in the ideal image, each pointing away from the corner."""
    c = np.array([template.u_px, template.v_px], dtype=float)
    a, b = template.top_angle_rad, template.right_angle_rad
    top = Line2D(c, np.array([np.cos(a), np.sin(a)])).oriented(AWAY["top"])
    right = Line2D(c, np.array([-np.sin(b), np.cos(b)])).oriented(AWAY["right"])
    return {"top": top, "right": right}


def _shift(line: Line2D, name: EdgeName, offset_px: float) -> Line2D:
    return Line2D(line.point + offset_px * into_opening(line, name), line.direction)


def _window(lens: Lens, line: Line2D, config: GapVisionConfig) -> F64:
    """Places (px along the line from the corner) of the window that lie inside the image, 1 px apart."""
    t = np.arange(config.start_px, config.start_px + config.length_px + 1e-9, 1.0)
    ideal = line.at(t)
    m = float(config.border_margin_px)
    lo = np.array([m, m])
    hi = np.array([lens.width_px - 1 - m, lens.height_px - 1 - m])
    near = np.all((ideal > lo - 200.0) & (ideal < hi + 200.0), axis=1)
    if not np.any(near):
        return t[:0]
    raw = lens.distort(ideal[near])
    inside = np.zeros(len(t), dtype=bool)
    inside[np.flatnonzero(near)] = np.all((raw >= lo) & (raw <= hi), axis=1)
    return t[inside]


def _edge_config(config: GapVisionConfig, lens: Lens, name: EdgeName, line: Line2D, corner: F64) -> VisionConfig:
    """The corner detector's edge settings for one window: its region of interest ends where the window does."""
    end = lens.distort(corner[None, :] + (config.start_px + config.length_px) * line.direction[None, :])[0]
    m = config.border_margin_px
    W, H = lens.width_px, lens.height_px
    if name == "top":
        x0 = int(np.clip(np.floor(end[0]) - m, 0, W - 64))
        roi = RoiConfig(x_px=x0, y_px=0, width_px=W - x0, height_px=H)
    else:
        h = int(np.clip(np.ceil(end[1]) + m + 1, 64, H))
        roi = RoiConfig(x_px=0, y_px=0, width_px=W, height_px=h)
    fit = FitConfig(
        arc_exclusion_px=config.start_px, border_margin_px=m, max_blur_sigma_px=config.max_blur_sigma_px,
        subpixel_band_px=config.ransac_band_px, robust_k=config.robust_k, seed=config.seed,
        max_edge_bump=config.max_edge_bump,
    )
    limits = LimitsConfig(
        min_edge_points=config.min_points, max_fit_rms_px=config.max_rms_px, min_contrast_dn=config.min_contrast_dn,
        max_bow_px=config.max_bow_px,
    )
    return VisionConfig(roi=roi, fit=fit, limits=limits)


def measure_gaps(
    image: NDArray[np.uint8],
    lens: Lens,
    template: CornerFeatures,
    config: GapVisionConfig,
    *,
    gap_px_expected: float,
    feature: FeatureConfig | None = None,
    opening_polarity: str = "darker",
    taught: TaughtProfile | None = None,
) -> GapMeasurement:
    """Find the opening's and the glass's top and right edges in a raw inspection image.

    Args:
        image: the raw 8-bit frame at the shooting pose.
        lens: the calibrated lens (points are undistorted, the image is not).
        template: the taught corner features; the opening's corner lies within a few px of them.
        config: ``[vision.gap]``.
        gap_px_expected: the nominal gap between the opening's and the glass's edges in pixels
            (the drawing's gap over the nine-point map's mm per px).
        feature: the recipe's feature-edge rule (``[vision.feature]``; default: the wall's edge).
        opening_polarity: "darker" (the default), "brighter" or "auto" (``[vision] opening_polarity``):
            how the opening looks beside the wall; "auto" takes the strongest step near the template's line.
        taught: the template's edge profiles (None: not recorded): the opening's edge must be the one
            step whose neighbourhood outside the glass's search window is the taught one.

    Raises ValueError only for a wrong call; whatever the image shows, the answer is a
    GapMeasurement, refused with a reason when an edge is missing or fails its limits.
    """
    img = lens.check_image(image)
    if not np.isfinite(gap_px_expected) or gap_px_expected <= 0:
        raise ValueError(f"gap_px_expected must be a positive number of pixels, got {gap_px_expected!r}")
    if opening_polarity not in ("darker", "brighter", "auto"):
        raise ValueError(f'opening_polarity must be "darker", "brighter" or "auto", got {opening_polarity!r}')
    feature = FeatureConfig() if feature is None else feature
    darker = None if opening_polarity == "auto" else opening_polarity == "darker"
    seeds = template_lines(template)
    start = float(config.start_px)
    profiles: dict[str, EdgeProfile] = {}
    places: dict[str, tuple[float, float]] = {}
    opening_seeds: dict[EdgeName, Line2D] = {}
    glass_seeds: dict[EdgeName, Line2D] = {}
    glass_dark: dict[EdgeName, bool] = {}
    opening_dark: dict[EdgeName, bool] = {}
    try:
        for name in EDGE_NAMES:
            along = _window(lens, seeds[name], config)
            if len(along) < config.cross_sections:
                raise GapRefused(
                    GapRefusal.EDGE_MISSING,
                    f"the {name} edge's straight part ({start:g} to {start + config.length_px:g} px from the template's "
                    f"corner) has only {len(along)} px inside the image (vision.gap.border_margin_px = "
                    f"{config.border_margin_px} from its border), fewer than vision.gap.cross_sections = "
                    f"{config.cross_sections}: set vision.gap.start_px and length_px (a recipe's in its "
                    "[process.recipes.vision.gap]) so the window lies in the image, or check that the camera stood at "
                    "the shooting pose",
                )
            prof, o_step, g_step = find_gap_steps(img, lens, name, seeds[name], along, config, feature, darker, gap_px_expected)
            profiles[name] = prof
            _check_taught(prof, name, o_step, taught, feature, gap_px_expected - config.glass_search_px)
            places[name] = (o_step.offset_px, g_step.offset_px)
            opening_seeds[name] = _shift(seeds[name], name, o_step.offset_px)
            glass_seeds[name] = _shift(seeds[name], name, g_step.offset_px)
            glass_dark[name] = g_step.change_dn < 0.0
            opening_dark[name] = o_step.change_dn < 0.0
    except GapRefused as r:
        return GapMeasurement(r.refusal, r.message, start, profiles=profiles or None, steps_px=places or None)

    edges: dict[str, EdgeMeasurement] = {}
    checks: list[Check] = []
    rng = np.random.default_rng(config.seed)
    try:
        for which, lines in (("opening", opening_seeds), ("glass", glass_seeds)):
            corner = intersect(lines["top"], lines["right"])
            if corner is None:
                raise GapRefused(GapRefusal.EDGE_MISSING, f"the {which}'s two edges are parallel: no corner")
            for name in EDGE_NAMES:
                cfg = _edge_config(config, lens, name, lines[name], corner)
                dark = opening_dark[name] if which == "opening" else glass_dark[name]
                try:
                    edge, edge_checks = measure_edge(
                        img, lens, name, lines[name], corner, cfg, SUBPIXEL_SEARCH_PX, dark, rng, INSPECTION_SETTINGS
                    )
                except Refused as r:
                    raise GapRefused(_as_gap_refusal(r.refusal.value), f"the {which}'s {name} edge: {r.message}") from None
                edges[f"{which}_{name}"] = edge
                checks += edge_checks
                failed = [c for c in edge_checks if not c.passed]
                if failed:
                    raise GapRefused(
                        _as_gap_refusal(failed[0].refusal.value),
                        f"the {which}'s {name} edge: refused: {failed[0].describe()}{_points_hint(failed[0], config)}",
                    )
    except GapRefused as r:
        return GapMeasurement(
            r.refusal, r.message, start, profiles=profiles, steps_px=places, checks=tuple(checks), **edges  # type: ignore[arg-type]
        )
    return GapMeasurement(None, "gaps measured", start, profiles=profiles, steps_px=places, checks=tuple(checks), **edges)  # type: ignore[arg-type]


def _check_taught(
    prof: EdgeProfile, name: str, opening: ProfileStep, taught: TaughtProfile | None, feature: FeatureConfig,
    glass_from_px: float,
) -> None:
    """Refuse an opening's edge that is not the step the taught profile finds (cellctl.vision.taught_profile).

    Only steps outside the glass's search window are compared (``glass_from_px`` from the template's line).
    """
    edge = taught.edges.get(name) if taught is not None and feature.taught_profile else None
    if taught is None or edge is None:
        return
    if (problem := rule_problem(taught, feature)) is not None:
        raise GapRefused(GapRefusal.OPENING_EDGE_NOT_FOUND, f"the {name} edge: {problem}")
    k, why = match_taught(prof, edge, opening.change_dn < 0.0, feature, below_px=glass_from_px)
    if k is None:
        raise GapRefused(GapRefusal.OPENING_EDGE_NOT_FOUND, f"the {name} edge: {why}")
    if prof.steps[k] != opening:
        raise GapRefused(
            GapRefusal.OPENING_EDGE_NOT_FOUND,
            f"the {name} edge: the recipe's rule picks the step at {opening.offset_px:+.1f} px, the taught profile the one "
            f"at {prof.steps[k].offset_px:+.1f} px (from the template's line): the car body shows another edge than "
            "taught; teach the recipe again if it changed, or set [vision.feature]",
        )


def _points_hint(check: Check, config: GapVisionConfig) -> str:
    """For too few edge points: the settings of the window they are measured in (empty for other checks)."""
    if not check.name.endswith("edge points"):
        return ""
    return (f" (vision.gap.min_points): the window vision.gap.start_px = {config.start_px:g}, length_px = "
            f"{config.length_px:g} may run out of the image; set them (a recipe's in its [process.recipes.vision.gap]) "
            "so it lies inside")


def _as_gap_refusal(value: str) -> GapRefusal:
    """The edge measurement's refusal (cellctl.vision.quality.Refusal) as the inspection's."""
    try:
        return GapRefusal(value)
    except ValueError:
        return GapRefusal.EDGE_MISSING
