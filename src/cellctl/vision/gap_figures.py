"""The inspection's in-plane figures: the four edge lines of the image turned into millimetres (issue 16).

The nine-point map (cellctl.vision.ninepoint, paper 4.3 step 1) takes undistorted pixels to mm in
the workpiece plane at the shooting pose (T0's axes: x right, y down). It is affine, so it takes
the image's lines to lines. It holds for points in the wall's plane; a glass whose outer surface
lies ``dz`` deeper (+ into the wall) is seen smaller about the optical axis: a point at lateral
position q (from the axis' foot point f on the wall) at depth D + dz projects as the wall point
f + (q - f) D / (D + dz), D the working distance. The glass's lines are corrected by the inverse,
a scaling about f by (D + dz) / D, f being the principal point mapped through the nine-point map
(the camera square to the wall).

From the four lines in mm:

- the opening's corner O (its lines' intersection) and direction phi_o (the mean of its top edge's
  angle to x and its right edge's angle to y);
- the glass's tangent corner C (its lines' intersection) and direction phi_g the same way;
- the gaps: from the point ``reference_along_mm`` along the opening's top (right) edge from O, the
  perpendicular distance to the glass's top (right) line, positive into the opening;
- the glass's corner frame G: the tangent corner lies at (-gap, +gap) in G (the nominal gap), so
  G's origin is C - R(phi_g) (-gap, gap); its offset from the opening, in the opening's axes,
  is (dX, dY) = R(-phi_o) (G - O) and dRz = phi_g - phi_o: the in-plane part of the install
  deviation E = inv(T) @ G that the twin scores.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.planar import rot2, wrap_angle
from cellctl.vision.lines import Line2D, intersect
from cellctl.vision.ninepoint import AffineMap

if TYPE_CHECKING:
    from cellctl.vision.gap import GapMeasurement

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class GapLines:
    """The four fitted lines in the ideal (undistorted) image, directions pointing away from the corner."""

    opening_top: Line2D
    opening_right: Line2D
    glass_top: Line2D
    glass_right: Line2D


@dataclass(frozen=True)
class InPlaneGaps:
    """The glass against the opening in the workpiece plane (mm, rad; module docstring).

    Attributes:
        dx_mm, dy_mm, drz_rad: the glass corner frame's in-plane offset from the opening's corner
            frame, in the opening's axes.
        top_gap_mm, right_gap_mm: the gaps at ``reference_along_mm`` from the opening's corner.
        top_angle_rad, right_angle_rad: each glass edge's angle to the opening's, positive from x
            towards y.
        opening_corner_mm, opening_angle_rad: the opening's virtual corner and direction in the map's frame.
        glass_corner_mm, glass_angle_rad: the glass's tangent corner (parallax corrected) and direction.
        parallax_scale: (D + dz) / D, applied to the glass's lines about ``foot_mm``.
    """

    dx_mm: float
    dy_mm: float
    drz_rad: float
    top_gap_mm: float
    right_gap_mm: float
    top_angle_rad: float
    right_angle_rad: float
    reference_along_mm: float
    opening_corner_mm: F64
    opening_angle_rad: float
    glass_corner_mm: F64
    glass_angle_rad: float
    parallax_scale: float
    foot_mm: F64

    def as_dict(self) -> dict[str, float | None]:
        """The scalar figures by name (angles in degrees, named so; None: not measured), for a cycle record."""
        return {
            "dx_mm": self.dx_mm,
            "dy_mm": self.dy_mm,
            "drz_deg": math.degrees(self.drz_rad),
            "top_gap_mm": self.top_gap_mm,
            "right_gap_mm": self.right_gap_mm,
            "top_angle_deg": math.degrees(self.top_angle_rad),
            "right_angle_deg": math.degrees(self.right_angle_rad) if math.isfinite(self.right_angle_rad) else None,
            "reference_along_mm": self.reference_along_mm,
            "parallax_scale": self.parallax_scale,
        }


def line_to_mm(line: Line2D, nine_point: AffineMap, *, foot_mm: F64 | None = None, scale: float = 1.0) -> Line2D:
    """A line of the ideal image in the map's mm, optionally scaled by ``scale`` about ``foot_mm`` (parallax)."""
    ends = nine_point.apply(np.vstack([line.point, line.point + 100.0 * line.direction]))
    if foot_mm is not None:
        ends = foot_mm + (ends - foot_mm) * scale
    d = ends[1] - ends[0]
    return Line2D(ends[0], d / np.linalg.norm(d))


def _frame(top: Line2D, right: Line2D) -> tuple[F64, float]:
    """Corner and direction of a corner frame from its top (pointing to -x) and right (to +y) edge lines."""
    corner = intersect(top, right)
    if corner is None:
        raise ValueError("the edge lines are parallel: no corner")
    x_hat, y_hat = -top.direction, right.direction
    a_top = math.atan2(x_hat[1], x_hat[0])
    a_right = math.atan2(-y_hat[0], y_hat[1])
    return corner, wrap_angle(a_top + 0.5 * wrap_angle(a_right - a_top))


def _gap(opening: Line2D, glass: Line2D, at_mm: float, corner: F64, inward: F64) -> float:
    """Distance from the point ``at_mm`` along the opening's line from its corner to the glass's line, along ``inward``."""
    p = corner + at_mm * opening.direction
    n = glass.normal if float(glass.normal @ inward) >= 0.0 else -glass.normal
    return float((glass.point - p) @ n)


def _turn(a: F64, b: F64) -> float:
    """Signed angle from direction a to direction b (positive from x towards y)."""
    return math.atan2(a[0] * b[1] - a[1] * b[0], float(a @ b))


def in_plane_from_gaps(
    gaps: GapMeasurement | GapLines,
    nine_point: AffineMap,
    *,
    nominal_gap_mm: float,
    dz_mm: float,
    working_distance_mm: float,
    principal_point_px: tuple[float, float],
    reference_along_mm: float | None = None,
) -> InPlaneGaps:
    """The glass's in-plane figures against the opening from the inspection image's four lines.

    Args:
        gaps: an accepted :func:`cellctl.vision.gap.measure_gaps` answer, or its four lines.
        nine_point: undistorted pixels to mm in the workpiece plane at the shooting pose.
        nominal_gap_mm: the drawing's gap; the glass's tangent corner lies at (-gap, +gap) in G.
        dz_mm: how far the glass's outer surface lies behind the wall (+ into the wall), e.g. from
            the laser's flush; 0 leaves out the parallax correction.
        working_distance_mm: the camera's distance D to the wall along its optical axis.
        principal_point_px: the lens's principal point (cx, cy): the optical axis' foot in the image.
        reference_along_mm: where along each opening edge from its corner the gaps are given;
            default: where the measured straight part starts (``gaps.start_px`` in mm; required
            with bare lines).

    Raises ValueError when the measurement was refused or an argument is out of range.
    """
    if isinstance(gaps, GapLines):
        lines, start_px = gaps, None
    else:
        lines, start_px = gaps.lines, float(gaps.start_px)
    if not (math.isfinite(working_distance_mm) and working_distance_mm > 0):
        raise ValueError(f"working_distance_mm must be a positive number, got {working_distance_mm!r}")
    if not (math.isfinite(dz_mm) and abs(dz_mm) < 0.5 * working_distance_mm):
        raise ValueError(f"dz_mm must be a finite depth well below the working distance, got {dz_mm!r}")
    if not (math.isfinite(nominal_gap_mm) and nominal_gap_mm > 0):
        raise ValueError(f"nominal_gap_mm must be a positive number, got {nominal_gap_mm!r}")
    foot = nine_point.apply(np.asarray(principal_point_px, dtype=float)[None, :])[0]
    scale = (working_distance_mm + dz_mm) / working_distance_mm
    o_top, o_right = (line_to_mm(line, nine_point) for line in (lines.opening_top, lines.opening_right))
    g_top, g_right = (line_to_mm(line, nine_point, foot_mm=foot, scale=scale) for line in (lines.glass_top, lines.glass_right))
    O, phi_o = _frame(o_top, o_right)
    C, phi_g = _frame(g_top, g_right)
    g = float(nominal_gap_mm)
    G = C - rot2(phi_g) @ np.array([-g, g])
    d = rot2(-phi_o) @ (G - O)
    if reference_along_mm is None and start_px is None:
        raise ValueError("reference_along_mm is needed with bare lines (a measurement gives its window's start)")
    at = float(reference_along_mm) if reference_along_mm is not None else float(start_px) * nine_point.mm_per_px  # type: ignore[arg-type]
    y_hat = rot2(phi_o) @ np.array([0.0, 1.0])
    x_hat = rot2(phi_o) @ np.array([1.0, 0.0])
    return InPlaneGaps(
        dx_mm=float(d[0]),
        dy_mm=float(d[1]),
        drz_rad=wrap_angle(phi_g - phi_o),
        top_gap_mm=_gap(o_top, g_top, at, O, y_hat),
        right_gap_mm=_gap(o_right, g_right, at, O, -x_hat),
        top_angle_rad=_turn(-o_top.direction, -g_top.direction),
        right_angle_rad=_turn(o_right.direction, g_right.direction),
        reference_along_mm=at,
        opening_corner_mm=O,
        opening_angle_rad=phi_o,
        glass_corner_mm=C,
        glass_angle_rad=phi_g,
        parallax_scale=scale,
        foot_mm=foot,
    )
