"""The inspection's in-plane figures from four lines (cellctl.vision.gap_figures): exact for a known glass seen through
a known map and recess; an opening out of square measured from the direction between its two edges (as the corner
detector gives T its rotation); a recess or a nominal gap that cannot be a glass's refused rather than scaled into the
figures (the last rules from a mutation run).

The four lines are built in millimetres from a known opening and a known glass and taken to pixels through a
known nine-point map, so the expected figures are the construction's.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cellctl.vision.gap_figures import GapLines, InPlaneGaps, in_plane_from_gaps
from cellctl.vision.lines import Line2D
from cellctl.vision.ninepoint import AffineMap

D = 400.0
L = 0.0762 * np.eye(2)  # mm per px, the camera square to the wall
C0 = np.array([-77.0, -78.0])
NINE = AffineMap(np.column_stack([L, C0]), np.zeros(9), 0.0, 0.0)
PRINCIPAL = (1014.7, 1012.0)


def _rot(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def _line_px(
    point_mm: np.ndarray, direction_mm: np.ndarray, nine: AffineMap = NINE, foot: np.ndarray | None = None, seen_scale: float = 1.0
) -> Line2D:
    """The line through ``point_mm`` along ``direction_mm`` (mm on the wall) in pixels through ``nine``; a glass recessed
    by dz is seen on the wall's plane pulled toward the foot point ``foot`` by ``seen_scale`` = (D + dz) / D."""
    ends = np.array([point_mm, point_mm + 50.0 * direction_mm])
    if foot is not None:
        ends = foot + (ends - foot) / seen_scale
    px = (ends - nine.matrix[:, 2]) @ np.linalg.inv(nine.matrix[:, :2]).T  # mm = L px + c, inverted
    d = px[1] - px[0]
    return Line2D(px[0], d / np.linalg.norm(d))


def _figures(top_skew: float, right_skew: float, dx: float, dy: float, drz: float, g: float = 5.0) -> InPlaneGaps:
    """An opening whose top edge turns ``top_skew`` from x and right edge ``right_skew`` from y (rad, + from x to y),
    and a square glass at (dx, dy, drz) from the opening's frame (the bisecting direction), seen flush (dz = 0)."""
    O = np.array([0.4, -0.3])
    phi_o = 0.5 * (top_skew + right_skew)
    G = O + _rot(phi_o) @ np.array([dx, dy])
    phi_g = phi_o + drz
    C = G + _rot(phi_g) @ np.array([-g, g])  # the glass's tangent corner
    lines = GapLines(
        _line_px(O, -(_rot(top_skew) @ [1.0, 0.0])), _line_px(O, _rot(right_skew) @ [0.0, 1.0]),
        _line_px(C, -(_rot(phi_g) @ [1.0, 0.0])), _line_px(C, _rot(phi_g) @ [0.0, 1.0]),
    )  # fmt: skip
    return in_plane_from_gaps(lines, NINE, nominal_gap_mm=g, dz_mm=0.0, working_distance_mm=D,
                              principal_point_px=PRINCIPAL, reference_along_mm=30.0)  # fmt: skip


def test_an_opening_out_of_square_is_measured_from_the_direction_between_its_edges() -> None:
    # A body whose opening is 0.23 deg out of square (its top edge turned +0.115 deg, its right edge -0.115 deg):
    # T's rotation is the mean of the two (cellctl.vision.corner), so a square glass installed on that
    # bisector with dRz = 0.05 deg is measured at 0.05 deg, and its offset in the bisector's axes.
    dx, dy, drz = 0.25, -0.15, math.radians(0.05)
    fig = _figures(0.002, -0.002, dx, dy, drz)
    assert fig.opening_angle_rad == pytest.approx(0.0, abs=1e-12)
    assert (fig.dx_mm, fig.dy_mm, fig.drz_rad) == pytest.approx((dx, dy, drz), abs=1e-9)
    # the same glass on a square opening turned by the same mean reads the same figures
    square = _figures(0.0, 0.0, dx, dy, drz)
    assert (square.dx_mm, square.dy_mm, square.drz_rad) == pytest.approx((dx, dy, drz), abs=1e-9)


def _square_lines() -> GapLines:
    """The opening square at (0.4, -0.3) mm, a square glass's tangent corner at (-4.5, 4.8): the glass 0.1 mm off
    along x and y with the nominal 5 mm gap."""
    O, C, x, y = np.array([0.4, -0.3]), np.array([-4.5, 4.8]), np.array([1.0, 0.0]), np.array([0.0, 1.0])
    return GapLines(_line_px(O, -x), _line_px(O, y), _line_px(C, -x), _line_px(C, y))


@pytest.mark.parametrize("dz_mm", [0.5 * D, -0.5 * D, 300.0])
def test_a_recess_of_half_the_working_distance_is_refused_not_scaled_into_the_glass(dz_mm: float) -> None:
    # a recess is a few mm; half the working distance would scale the glass's lines about the foot point by 1.5
    # (or to nothing): a broken flush, not a glass behind the wall
    with pytest.raises(ValueError, match="dz_mm must be a finite depth well below the working distance"):
        in_plane_from_gaps(_square_lines(), NINE, nominal_gap_mm=5.0, dz_mm=dz_mm, working_distance_mm=D,
                           principal_point_px=PRINCIPAL, reference_along_mm=30.0)  # fmt: skip


@pytest.mark.parametrize("gap_mm", [0.0, -5.0])
def test_a_nominal_gap_that_is_no_gap_is_refused(gap_mm: float) -> None:
    # with -5 mm the glass's frame would be placed 10 mm off along both axes from the same lines
    fine = in_plane_from_gaps(_square_lines(), NINE, nominal_gap_mm=5.0, dz_mm=0.0, working_distance_mm=D,
                              principal_point_px=PRINCIPAL, reference_along_mm=30.0)  # fmt: skip
    assert (fine.dx_mm, fine.dy_mm) == pytest.approx((0.1, 0.1), abs=1e-9)
    with pytest.raises(ValueError, match="nominal_gap_mm must be a positive number"):
        in_plane_from_gaps(_square_lines(), NINE, nominal_gap_mm=gap_mm, dz_mm=0.0, working_distance_mm=D,
                           principal_point_px=PRINCIPAL, reference_along_mm=30.0)  # fmt: skip


def test_in_plane_figures_from_exact_lines() -> None:
    """Lines built from a known glass in mm, seen through a map and a recess: the figures come back exact."""
    skewed = 0.0762 * _rot(0.01) @ np.array([[1.0, 0.002], [0.0, 1.001]])  # mm per px, turned and sheared
    nine = AffineMap(np.column_stack([skewed, C0]), np.zeros(9), 0.0, 0.0)
    principal = PRINCIPAL
    foot = nine.apply(np.array([principal]))[0]
    O, phi_o = np.array([0.4, -0.3]), 0.003
    dx, dy, drz, dz, g = 0.25, -0.15, math.radians(0.12), 0.6, 5.0
    k = (D + dz) / D
    R_o = _rot(phi_o)
    C = O + R_o @ (np.array([dx, dy]) + _rot(drz) @ np.array([-g, g]))  # the glass's tangent corner (true, mm)
    x_o, y_o = R_o @ [1.0, 0.0], R_o @ [0.0, 1.0]
    x_g, y_g = R_o @ _rot(drz) @ [1.0, 0.0], R_o @ _rot(drz) @ [0.0, 1.0]
    lines = GapLines(_line_px(O, -x_o, nine), _line_px(O, y_o, nine), _line_px(C, -x_g, nine, foot, k), _line_px(C, y_g, nine, foot, k))
    a = 33.0
    fig = in_plane_from_gaps(
        lines, nine, nominal_gap_mm=g, dz_mm=dz, working_distance_mm=D, principal_point_px=principal, reference_along_mm=a
    )
    assert (fig.dx_mm, fig.dy_mm, fig.drz_rad) == pytest.approx((dx, dy, drz), abs=1e-9)
    assert fig.opening_corner_mm == pytest.approx(O, abs=1e-9) and fig.opening_angle_rad == pytest.approx(phi_o, abs=1e-12)
    # Gaps in the opening's frame: the glass's top line at x = -a, its right line at y = a, perpendicular distances.
    q = np.array([dx, dy]) + _rot(drz) @ np.array([-g, g])
    assert fig.top_gap_mm == pytest.approx((q[1] + (-a - q[0]) * math.tan(drz)) * math.cos(drz), abs=1e-9)
    assert fig.right_gap_mm == pytest.approx(-(q[0] - (a - q[1]) * math.tan(drz)) * math.cos(drz), abs=1e-9)
    assert (fig.top_angle_rad, fig.right_angle_rad) == pytest.approx((drz, drz), abs=1e-12)
    # Without the recess, the glass's corner moves away from the foot point by dz / D of its distance.
    flat = in_plane_from_gaps(
        lines, nine, nominal_gap_mm=g, dz_mm=0.0, working_distance_mm=D, principal_point_px=principal, reference_along_mm=a
    )
    assert flat.glass_corner_mm == pytest.approx(foot + (C - foot) / k, abs=1e-9)
    with pytest.raises(ValueError, match="reference_along_mm"):
        in_plane_from_gaps(lines, nine, nominal_gap_mm=g, dz_mm=0.0, working_distance_mm=D, principal_point_px=principal)
