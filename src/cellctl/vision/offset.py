"""From corner features to the in-plane offset T' of the workpiece (paper eq. 16 and section 4.3).

Eq. 16 compares the corner found now with the one found at teaching, both in the ideal image:

    du = u_d - u,   dv = v_d - v,   dtheta_z = theta_d - theta

T' (cellctl.geometry.planar.PlanarOffset) is the pose of the true workpiece frame in the estimated
one T1, within the wall plane. The camera stands in the same relation to T1 as it stood to T0
when the template was taught, so the corner, which is the true frame's origin, appears displaced
by T''s translation and the edges turned by its angle. A true frame to the right of T1 (dx > 0)
puts the corner to the right in the image (u > u_d, du < 0), hence the minus signs below; and a
frame turned from x towards y turns the edges from u towards v (theta > theta_d).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellctl.geometry.planar import PlanarOffset, rot2
from cellctl.vision.corner import CornerFeatures
from cellctl.vision.ninepoint import AffineMap


@dataclass(frozen=True)
class Deviation:
    """Eq. 16: taught minus current, in ideal-image pixels and radians."""

    du_px: float
    dv_px: float
    dtheta_rad: float


def deviation(taught: CornerFeatures, current: CornerFeatures) -> Deviation:
    """The positioning deviation of eq. 16."""
    return Deviation(taught.u_px - current.u_px, taught.v_px - current.v_px, taught.theta_rad - current.theta_rad)


def offset_from_scale(taught: CornerFeatures, current: CornerFeatures, mm_per_px: float) -> PlanarOffset:
    """T' from eq. 16 and the checkerboard scale s (eq. 15), as the paper converts it.

    The pixel deviation is scaled by s and turned from the image's axes into the workpiece's by
    the taught corner angle theta_d (the top edge runs along the workpiece's x axis), which makes
    it exact for a camera square to the wall; with theta_d = 0 it is the paper's plain scaling.
    """
    if not np.isfinite(mm_per_px) or mm_per_px <= 0:
        raise ValueError(f"mm_per_px must be a positive number, got {mm_per_px!r}; calibrate the pixel scale")
    dev = deviation(taught, current)
    dxy = mm_per_px * (rot2(-taught.theta_rad) @ np.array([-dev.du_px, -dev.dv_px]))
    return PlanarOffset(float(dxy[0]), float(dxy[1]), -dev.dtheta_rad)


def _edge_direction(angle: float, edge: str) -> np.ndarray:
    """The image direction of an edge turned by ``angle``: the top edge along u, the right along v."""
    base = np.array([1.0, 0.0]) if edge == "top" else np.array([0.0, 1.0])
    return rot2(angle) @ base


def turn_measured(taught: CornerFeatures, current: CornerFeatures) -> bool:
    """Whether an offset turns: an edge whose angle both the template and the shot have (see
    :func:`offset_from_map`); a shot seeing only an edge the template lacks corrects no turn."""
    pairs = ((taught.top_angle_rad, current.top_angle_rad), (taught.right_angle_rad, current.right_angle_rad))
    return any(np.isfinite(a_d) and np.isfinite(a) for a_d, a in pairs)


def offset_from_map(
    taught: CornerFeatures, current: CornerFeatures, nine_point: AffineMap, feature_mm: tuple[float, float] = (0.0, 0.0)
) -> PlanarOffset:
    """T' from eq. 16 through the nine-point map (any camera rotation, unequal axis scales).

    Translation: the map's linear part applied to the feature's displacement. Rotation: each edge's
    taught and current directions (those both shots saw: a finite angle) are carried into the
    workpiece plane by the map and the angle between them is taken; the edges' angles are averaged
    (0 when no edge was seen). ``feature_mm`` is where the feature lies in T (the arc's centre for
    a large corner radius): T' turns about T's origin, so the feature moves by (R - I) c besides t.
    """
    L = nine_point.linear
    d_uv = np.array([current.u_px - taught.u_px, current.v_px - taught.v_px])
    dxy = L @ d_uv
    turns = []
    for edge, a_d, a in (
        ("top", taught.top_angle_rad, current.top_angle_rad),
        ("right", taught.right_angle_rad, current.right_angle_rad),
    ):
        if not (np.isfinite(a_d) and np.isfinite(a)):
            continue
        w_d = L @ _edge_direction(a_d, edge)
        w = L @ _edge_direction(a, edge)
        turns.append(float(np.arctan2(w_d[0] * w[1] - w_d[1] * w[0], w_d @ w)))
    dtheta = float(np.mean(turns)) if turns else 0.0
    c = np.asarray(feature_mm, dtype=float)
    t = dxy - (rot2(dtheta) - np.eye(2)) @ c
    return PlanarOffset(float(t[0]), float(t[1]), dtheta)
