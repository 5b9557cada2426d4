"""What the twin's camera truly sees of the window corner: the truth for vision tests.

"The corner" is the virtual sharp corner where the lines of the top and right straight edges
meet, the origin of the workpiece frame T (outside the rounded arc, r (sqrt(2) - 1) from it). Its
true image position is T's origin projected with distortion (``corner_px``);
``corner_undistorted_px`` is the same in the ideal pinhole image (same camera matrix A), where
the edges are straight; ``*_tangent_px`` are the raw edges' tangents at the corner.

Edges are parametrised by the distance ``a`` (mm) from the virtual corner: the top edge is
(x, y) = (-a, 0) in T, the right edge (0, a). A feature edge ``inset_mm`` into the opening
(negative: onto the wall) has lines y = inset and x = -inset and its corner at (-inset, inset, 0).

An installed glass (cellctl.sim.glass) has its truth in :func:`glass_truth`: the gaps, the
in-plane deviation and its corner in the image.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.geometry.pose import apply_pose, check_pose, invert_pose
from cellctl.geometry.rotation import matrix_to_xyz_fixed
from cellctl.sim.camera_model import CameraModel
from cellctl.sim.glass import InstalledGlass
from cellctl.sim.world import World

EdgeName = Literal["top", "right"]
EDGES: tuple[EdgeName, EdgeName] = ("top", "right")

F64 = NDArray[np.float64]


def edge_points_T(world: World, edge: EdgeName, a_mm: ArrayLike, *, inset_mm: float = 0.0) -> F64:
    """Points (N, 3) of an edge's line in T at along-edge distances ``a_mm`` from the corner.

    ``inset_mm`` offsets the line into the opening (see the module docstring).
    """
    a = np.atleast_1d(np.asarray(a_mm, dtype=float))
    zeros = np.zeros_like(a)
    d = float(inset_mm)
    if edge == "top":
        return np.column_stack([-d - a, zeros + d, zeros])
    if edge == "right":
        return np.column_stack([zeros - d, d + a, zeros])
    raise ValueError(f"edge must be 'top' or 'right', got {edge!r}")


def straight_range_mm(world: World, edge: EdgeName) -> tuple[float, float]:
    """The along-edge range (mm) of an edge's straight part, between the rounded corners."""
    length = world.width_mm if edge == "top" else world.height_mm
    return world.corner_radius_mm, length - world.corner_radius_mm


def edge_curve_px(
    camera: CameraModel, T_B_C: ArrayLike, world: World, edge: EdgeName, a_mm: ArrayLike, *, inset_mm: float = 0.0
) -> F64:
    """Distorted image positions (N, 2) of points of an edge's line (the projected true edge)."""
    return camera.project(apply_pose(world.T_B_T, edge_points_T(world, edge, a_mm, inset_mm=inset_mm)), T_B_C)


def visible_edge_interval(
    camera: CameraModel,
    T_B_C: ArrayLike,
    world: World,
    edge: EdgeName,
    *,
    margin_px: float = 8.0,
    samples: int = 4001,
) -> tuple[float, float] | None:
    """The longest along-edge interval (mm) of an edge's straight part that is in the image.

    Points count when they are in front of the camera and at least ``margin_px`` inside the image
    border. The ends are found on a grid of ``samples`` points (about 0.5 mm apart on the default
    2000 mm edge). Returns None when no part is visible.
    """
    T = check_pose(T_B_C, "T_B_C")
    a0, a1 = straight_range_mm(world, edge)
    if a1 <= a0:
        return None
    a = np.linspace(a0, a1, samples)
    P_C = apply_pose(invert_pose(T) @ world.T_B_T, edge_points_T(world, edge, a))
    front = P_C[:, 2] > 1e-6
    inside = np.zeros(samples, dtype=bool)
    if np.any(front):
        uv = camera.project_camera(P_C[front])
        ok = (
            (uv[:, 0] >= margin_px)
            & (uv[:, 0] <= camera.width - 1 - margin_px)
            & (uv[:, 1] >= margin_px)
            & (uv[:, 1] <= camera.height - 1 - margin_px)
        )
        inside[np.flatnonzero(front)[ok]] = True
    if not np.any(inside):
        return None
    # Longest run of consecutive visible samples.
    padded = np.concatenate([[False], inside, [False]])
    changes = np.flatnonzero(padded[1:] != padded[:-1])
    starts, ends = changes[0::2], changes[1::2]
    k = int(np.argmax(ends - starts))
    lo, hi = int(starts[k]), int(ends[k]) - 1
    if hi <= lo:
        return None
    return float(a[lo]), float(a[hi])


@dataclass(frozen=True)
class CornerTruth:
    """Where the window corner and its edges truly appear in one image (see ``corner_truth``).

    Attributes:
        corner_px: the virtual sharp corner (T's origin, or the inset corner) in the raw,
            distorted image (u, v).
        corner_undistorted_px: the same point in the ideal pinhole image (camera matrix A, no
            distortion), where a pipeline that undistorts first measures it.
        top_edge_dir_px, right_edge_dir_px: unit directions of the straight edges in the ideal
            image, pointing away from the corner (top edge towards the opening's far side, -x of T;
            right edge downwards, +y of T).
        top_edge_tangent_px, right_edge_tangent_px: unit tangents of the (curved) edges in the
            distorted image at the corner, pointing the same ways.
        edge_angle_rad: the angle of the top edge's line to the image u axis in the ideal image,
            atan2(dv, du) for its direction with du >= 0, in (-pi/2, pi/2]; 0 when the edge runs
            along the rows, positive when it falls to the right (v grows to the right).
        corner_angle_rad: the angle between the two edges at the corner in the ideal image.
        corner_in_image: whether ``corner_px`` lies inside the image.
        depth_mm: the corner's distance along the optical axis (Z in the camera frame).
    """

    corner_px: F64
    corner_undistorted_px: F64
    top_edge_dir_px: F64
    right_edge_dir_px: F64
    top_edge_tangent_px: F64
    right_edge_tangent_px: F64
    edge_angle_rad: float
    corner_angle_rad: float
    corner_in_image: bool
    depth_mm: float


def camera_pose_seeing_corner(
    camera: CameraModel,
    world: World,
    corner_px: tuple[float, float],
    *,
    distance_mm: float = 400.0,
    R_T_C: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """A camera pose T_B_C that sees the virtual corner at pixel ``corner_px`` (with distortion).

    The camera's axes are ``R_T_C`` in T (default: along T's, as at the taught shooting pose) and
    the corner lies ``distance_mm`` ahead of the camera along its optical axis. Exact: the
    corner's projection is ``corner_px`` to rounding.
    """
    R = np.eye(3) if R_T_C is None else np.asarray(R_T_C, dtype=float)
    if not np.isfinite(distance_mm) or distance_mm <= 0:
        raise ValueError(f"distance_mm must be a positive number, got {distance_mm!r}")
    xy = camera.undistort_pixels([corner_px])[0]
    t = -R @ (distance_mm * np.array([xy[0], xy[1], 1.0]))
    T_T_C = np.eye(4)
    T_T_C[:3, :3] = R
    T_T_C[:3, 3] = t
    return check_pose(world.T_B_T @ T_T_C, "T_B_C")


def _unit(v: F64) -> F64:
    return v / np.linalg.norm(v)


def corner_truth(camera: CameraModel, T_B_C: ArrayLike, world: World, inset_mm: float = 0.0) -> CornerTruth:
    """The true image of the window corner for a camera pose and a car-body placement.

    ``inset_mm`` gives the truth of a feature edge offset that far into the opening (negative:
    outwards), whose virtual corner is T's point (-inset, inset, 0); see the module docstring.
    Raises ValueError when the corner is behind the camera.
    """
    T = check_pose(T_B_C, "T_B_C")
    T_C_T = invert_pose(T) @ world.T_B_T
    step = 10.0  # mm along each edge; the ideal image of a straight line is straight
    d = float(inset_mm)
    if not np.isfinite(d):
        raise ValueError(f"inset_mm must be a finite number, got {inset_mm!r}")
    pts_T = np.vstack(
        [
            np.array([[0.0 - d, d, 0.0]]),
            edge_points_T(world, "top", [step], inset_mm=d),
            edge_points_T(world, "right", [step], inset_mm=d),
        ]
    )
    P_C = apply_pose(T_C_T, pts_T)
    if P_C[0, 2] <= 0.0:
        raise ValueError("the window corner lies behind the camera at this pose (Z <= 0 in the camera frame)")
    ideal = np.column_stack(
        [camera.fx * P_C[:, 0] / P_C[:, 2] + camera.cx, camera.fy * P_C[:, 1] / P_C[:, 2] + camera.cy]
    )
    top_dir = _unit(ideal[1] - ideal[0])
    right_dir = _unit(ideal[2] - ideal[0])
    h = 1e-3  # mm: central differences through the virtual corner along each edge's line
    tangents = []
    for edge in EDGES:
        ends = camera.project_camera(apply_pose(T_C_T, edge_points_T(world, edge, [-h, h], inset_mm=d)))
        tangents.append(_unit(ends[1] - ends[0]))
    corner = camera.project_camera(P_C[:1])[0]
    line = top_dir if top_dir[0] >= 0.0 else -top_dir
    angle = float(np.arctan2(line[1], line[0]))
    if angle <= -np.pi / 2:
        angle += np.pi
    inside = bool(0.0 <= corner[0] <= camera.width - 1 and 0.0 <= corner[1] <= camera.height - 1)
    return CornerTruth(
        corner_px=corner,
        corner_undistorted_px=ideal[0],
        top_edge_dir_px=top_dir,
        right_edge_dir_px=right_dir,
        top_edge_tangent_px=tangents[0],
        right_edge_tangent_px=tangents[1],
        edge_angle_rad=angle,
        corner_angle_rad=float(np.arccos(np.clip(top_dir @ right_dir, -1.0, 1.0))),
        corner_in_image=inside,
        depth_mm=float(P_C[0, 2]),
    )


@dataclass(frozen=True)
class GlassTruth:
    """What an installed glass truly is against the opening, and where it appears in one image.

    In-plane figures are in T's x-y plane with the glass's edges projected onto it along T's z (as
    a camera square to the wall, its parallax corrected, measures them).

    Attributes:
        E: the glass corner frame G in T (inv(T_B_T) @ T_B_G), as the twin scores the install.
        dx_mm, dy_mm, dz_mm: E's translation; drz_rad: its rotation about z (eq. 13's alpha).
        top_gap_mm, right_gap_mm: from the point ``reference_along_mm`` along the opening's top
            (right) edge from its virtual corner, the perpendicular distance to the glass's top
            (right) edge line, positive into the opening.
        top_angle_rad, right_angle_rad: the glass's edge against the opening's, positive turning
            from T's x towards y.
        glass_corner_T: the glass's tangent corner (where its edges' lines meet; (-gap, gap, 0)
            in G) in T, its z the glass's depth there (+ into the wall).
        glass_corner_px, glass_corner_undistorted_px: that corner in the raw and the ideal image.
    """

    E: NDArray[np.float64]
    dx_mm: float
    dy_mm: float
    dz_mm: float
    drz_rad: float
    top_gap_mm: float
    right_gap_mm: float
    reference_along_mm: float
    top_angle_rad: float
    right_angle_rad: float
    glass_corner_T: F64
    glass_corner_px: F64
    glass_corner_undistorted_px: F64


def _gap_to(E: NDArray[np.float64], a: F64, b: F64, point: F64, inward: F64) -> float:
    """Perpendicular distance (T's plane) from ``point`` to the line through G points a, b projected, along ``inward``."""
    qa, qb = apply_pose(E, np.vstack([a, b]))[:, :2]
    d = _unit(qb - qa)
    n = np.array([-d[1], d[0]])
    if float(n @ inward) < 0.0:
        n = -n
    return float((qa - point) @ n)


def glass_truth(
    camera: CameraModel, T_B_C: ArrayLike, world: World, glass: InstalledGlass, *, reference_along_mm: float
) -> GlassTruth:
    """The true figures of an installed glass against the opening, and its corner in the image at ``T_B_C``."""
    T = check_pose(T_B_C, "T_B_C")
    E = invert_pose(world.T_B_T) @ glass.T_B_G
    g = glass.edge_gap_mm
    a = float(reference_along_mm)
    top_gap = _gap_to(E, np.array([-a, g, 0.0]), np.array([-a - 100.0, g, 0.0]), np.array([-a, 0.0]), np.array([0.0, 1.0]))
    right_gap = _gap_to(E, np.array([-g, a, 0.0]), np.array([-g, a + 100.0, 0.0]), np.array([0.0, a]), np.array([-1.0, 0.0]))
    corner_T = apply_pose(E, np.array([-g, g, 0.0]))
    P_C = apply_pose(invert_pose(T) @ world.T_B_T, corner_T[None, :])
    if P_C[0, 2] <= 0.0:
        raise ValueError("the glass's corner lies behind the camera at this pose")
    ideal = np.array([camera.fx * P_C[0, 0] / P_C[0, 2] + camera.cx, camera.fy * P_C[0, 1] / P_C[0, 2] + camera.cy])
    return GlassTruth(
        E=E,
        dx_mm=float(E[0, 3]),
        dy_mm=float(E[1, 3]),
        dz_mm=float(E[2, 3]),
        drz_rad=float(matrix_to_xyz_fixed(E[:3, :3])[0]),
        top_gap_mm=top_gap,
        right_gap_mm=right_gap,
        reference_along_mm=a,
        top_angle_rad=float(np.arctan2(E[1, 0], E[0, 0])),
        right_angle_rad=float(np.arctan2(-E[0, 1], E[1, 1])),
        glass_corner_T=corner_T,
        glass_corner_px=camera.project_camera(P_C)[0],
        glass_corner_undistorted_px=ideal,
    )
