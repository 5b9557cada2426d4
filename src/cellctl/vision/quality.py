"""Quality figures of a corner measurement, the limits they are held to, and refusals.

A refusal is an answer: the detector returns it as a value with the reason and the figure that
failed, never as an exception, so the cycle can report it, raise an alarm and keep the image.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Generic, TypeVar

R = TypeVar("R", bound=Enum)


class Refusal(str, Enum):
    """Why the detector gives no corner."""

    CORNER_NOT_FOUND = "corner_not_found"  # no pair of lines forming the upper-right corner
    EDGE_MISSING = "edge_missing"  # one edge not found, or too few points on it
    LOW_CONTRAST = "low_contrast"  # wall against opening too faint to measure
    SATURATED = "saturated"  # too many edge profiles clipped at the sensor's top value
    POOR_FIT = "poor_fit"  # edge points scatter too much about their line, or too many outliers
    EDGE_BENT = "edge_bent"  # an edge is not straight (arc not left out, wrong distortion, glare)
    NOT_PERPENDICULAR = "not_perpendicular"  # the two edges do not meet at a right angle
    UNCERTAIN = "uncertain"  # the fits predict a corner uncertainty above the limit
    ARC_NOT_SEEN = "arc_not_seen"  # the rounded corner could not be measured to check the edges
    ARC_MISMATCH = "arc_mismatch"  # an edge line does not touch the arc: not the true edge
    FEATURE_NOT_FOUND = "feature_not_found"  # the recipe's feature edge is not among the edge's steps


class Refused(Exception, Generic[R]):
    """Internal: carries a refusal and its message out of a pipeline, which turns it into its value."""

    def __init__(self, refusal: R, message: str) -> None:
        super().__init__(message)
        self.refusal = refusal
        self.message = message


@dataclass(frozen=True)
class Check:
    """One quality figure against its limit; ``passed`` tells whether it is within it."""

    name: str
    value: float
    limit: float
    passed: bool
    refusal: Refusal
    unit: str = ""

    def describe(self) -> str:
        relation = "at least" if self.name.startswith("min ") else "at most"
        return f"{self.name} {self.value:.4g}{self.unit} (limit: {relation} {self.limit:g}{self.unit})"


def at_least(name: str, value: float, limit: float, refusal: Refusal, unit: str = "") -> Check:
    return Check(f"min {name}", float(value), float(limit), bool(value >= limit), refusal, unit)


def at_most(name: str, value: float, limit: float, refusal: Refusal, unit: str = "") -> Check:
    return Check(f"max {name}", float(value), float(limit), bool(value <= limit), refusal, unit)


@dataclass(frozen=True)
class EdgeQuality:
    """How one edge was measured.

    ``profiles``: profiles taken across the edge's straight part; ``points``: of them, those that
    gave a valid crossing; ``inliers``: points kept by RANSAC and the robust refit;
    ``rms_px``: RMS distance of the inliers from the fitted line; ``contrast_dn``: median wall
    minus opening grey level; ``blur_sigma_px``: median edge spread; ``bow_px``: sagitta of a
    parabola fitted to the residuals over the fitted span; ``length_px``: that span;
    ``saturated_fraction``: share of profiles clipped at the sensor's top value;
    ``sigma_angle_rad``: predicted 1-sigma of the edge's angle; ``uneven_background``: profiles
    left out because their plateau levels left the edge's lighting trend (glare, reflections).
    """

    profiles: int
    points: int
    inliers: int
    rms_px: float
    contrast_dn: float
    blur_sigma_px: float
    bow_px: float
    length_px: float
    saturated_fraction: float
    sigma_angle_rad: float
    uneven_background: int = 0

    @property
    def inlier_fraction(self) -> float:
        """Share of the usable points (valid, unsaturated, on a flat background) the line keeps."""
        return self.inliers / self.points if self.points else 0.0
