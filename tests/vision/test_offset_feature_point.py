"""Eq. 16's offset when the feature is not T's origin (issue 21: the arc's centre), against a known T'.

The camera looks square onto the wall with its axes along T's (the nine-point map a scale and a
small turn): the true frame T2 = T1 @ T' puts the opening's points p (in T2) at T' p in T1, so a
feature at c moves by (R - I) c + t and the edges turn by the angle of T'.
"""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.vision.corner import CornerFeatures
from cellctl.vision.ninepoint import AffineMap
from cellctl.vision.offset import offset_from_map

MM_PER_PX = 0.0762
TURN = np.radians(0.7)  # the camera's axes turned against T's by this much in the image
L = MM_PER_PX * np.array([[np.cos(TURN), -np.sin(TURN)], [np.sin(TURN), np.cos(TURN)]])
NINE_POINT = AffineMap(np.column_stack([L, [10.0, -5.0]]), np.zeros(9), 0.0, 0.0)
ARC_CENTRE_MM = (-150.0, 150.0)  # a 150 mm corner's arc centre in T


def _rot(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _shot(c_mm: tuple[float, float], t_mm: np.ndarray, dtheta: float, *, right_edge: bool) -> tuple[CornerFeatures, CornerFeatures]:
    """The taught and the current features of a feature at ``c_mm`` when the opening moves by T' = (t, dtheta)."""
    taught_uv = np.array([480.0, 2200.0])
    c = np.asarray(c_mm)
    moved = _rot(dtheta) @ c + t_mm - c  # in T1's mm
    current_uv = taught_uv + np.linalg.solve(L, moved)
    top0 = float(TURN)  # the top edge along T's x, seen turned by the camera's turn
    # An edge's image direction turns as the map's inverse turns T's direction (a similarity: by dtheta).
    right = (lambda a: a) if right_edge else (lambda a: float("nan"))
    taught = CornerFeatures(*taught_uv, top0, top0, right(top0))
    current = CornerFeatures(*current_uv, top0 + dtheta, top0 + dtheta, right(top0 + dtheta))
    return taught, current


@pytest.mark.parametrize(("t", "deg"), [((0.3, -0.2), 0.5), ((-1.5, 2.0), -2.0), ((0.0, 0.0), 1.0)])
def test_the_arc_centres_offset_gives_t_prime_about_ts_origin(t: tuple[float, float], deg: float) -> None:
    taught, current = _shot(ARC_CENTRE_MM, np.array(t), np.radians(deg), right_edge=False)
    off = offset_from_map(taught, current, NINE_POINT, ARC_CENTRE_MM)
    assert abs(off.dx_mm - t[0]) < 1e-6 and abs(off.dy_mm - t[1]) < 1e-6
    assert abs(off.dtheta_rad - np.radians(deg)) < 1e-9
    # Taking the arc's centre for T's origin (the rule removed) is off by (R - I) c: 2.6 mm at 1 deg.
    wrong = offset_from_map(taught, current, NINE_POINT)
    if deg:
        assert np.hypot(wrong.dx_mm - t[0], wrong.dy_mm - t[1]) > 1.0


def test_the_corner_method_is_unchanged_and_both_edges_count() -> None:
    taught, current = _shot((0.0, 0.0), np.array([0.4, -0.1]), np.radians(0.3), right_edge=True)
    off = offset_from_map(taught, current, NINE_POINT)
    assert abs(off.dx_mm - 0.4) < 1e-6 and abs(off.dy_mm + 0.1) < 1e-6 and abs(off.dtheta_rad - np.radians(0.3)) < 1e-9


def test_a_shot_without_an_edge_turns_nothing() -> None:
    taught, current = _shot(ARC_CENTRE_MM, np.array([0.2, 0.1]), 0.0, right_edge=False)
    blind = CornerFeatures(current.u_px, current.v_px, float("nan"), float("nan"), float("nan"))
    off = offset_from_map(taught, blind, NINE_POINT, ARC_CENTRE_MM)
    assert off.dtheta_rad == 0.0 and abs(off.dx_mm - 0.2) < 1e-6 and abs(off.dy_mm - 0.1) < 1e-6


def test_a_shot_seeing_only_an_edge_the_template_lacks_turns_nothing() -> None:
    # The door's template has its top edge only; a first shot of a body placed far off may see only
    # the right edge: it measures theta but corrects no turn, and says so (the cycle then lets the
    # first verification move be a first correction's size).
    from cellctl.vision.offset import turn_measured

    taught, current = _shot(ARC_CENTRE_MM, np.array([0.2, 0.1]), np.radians(0.4), right_edge=False)
    right_only = CornerFeatures(current.u_px, current.v_px, np.radians(0.4), float("nan"), np.radians(0.4))
    off = offset_from_map(taught, right_only, NINE_POINT, ARC_CENTRE_MM)
    assert off.dtheta_rad == 0.0 and not turn_measured(taught, right_only)
    assert turn_measured(taught, current) and abs(offset_from_map(taught, current, NINE_POINT, ARC_CENTRE_MM).dtheta_rad) > 0.0


def test_the_turn_is_the_mean_of_both_edges_turns() -> None:
    """Eq. 16's angle from both edges: each is one noisy measure of the same turn, so they are averaged."""
    taught = CornerFeatures(1000.0, 1000.0, np.pi / 2, 0.0, 0.0)
    current = CornerFeatures(1000.0, 1000.0, np.pi / 2, 0.010, 0.014)  # the edges' fits differ by 4 mrad
    offset = offset_from_map(taught, current, AffineMap(np.column_stack([MM_PER_PX * np.eye(2), [0.0, 0.0]]), np.zeros(9), 0.0, 0.0))
    assert offset.dtheta_rad == pytest.approx(0.012, abs=1e-12)
    only_top = CornerFeatures(1000.0, 1000.0, np.pi / 2, 0.010, float("nan"))  # the right edge out of view: the top's alone
    assert offset_from_map(taught, only_top, NINE_POINT).dtheta_rad == pytest.approx(0.010, abs=1e-12)
