"""Where the robot goes to collect calibration data: diverse, reachable, target in view.

Two planners, both pure functions of nominal geometry (what the engineer knows before
calibrating: the CAD mounting of camera and laser, roughly where the board or the wall is) and a
reach check supplied by the caller (the robot controller's, or the twin's):

- :func:`plan_board_views` for camera intrinsics and hand-eye: the camera looks at the board's
  centre from ``distance_mm`` while the flange tilts about axes spread evenly around the optical
  axis (golden-angle steps) and spins about it, so the relative rotations between any two views
  have axes spread over all three directions (Tsai needs at least two non-parallel axes;
  translation along an axis is unobservable when every rotation is about it). Every pose keeps
  the whole board with its border ``margin_px`` inside the image.
- :func:`plan_laser_poses` for the laser's r and l: from a set of arm stands (the wrist centre
  held still, only the wrist turning), the beam tilts about axes spread around it and meets a
  flat wall at distances swept over the sensor's range, so every direction is read near and far
  (see cellctl.calibration.laser).

A candidate that fails a check is retried with a smaller tilt; the reasons for every dropped
candidate are kept so the operator can see why the plan is shorter than asked.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.geometry.pose import Pose, apply_pose, check_pose, invert_pose, make_pose
from cellctl.geometry.rotation import (
    axis_angle_to_matrix,
    rot_z,
    rotation_angle_between,
)

F64 = NDArray[np.float64]
ReachCheck = Callable[[Pose], None]

GOLDEN_ANGLE_RAD = float(np.pi * (3.0 - np.sqrt(5.0)))
# Additive recurrences k * a mod 1 with these a fill [0, 1) evenly and are mutually independent
# (1/phi, and 1/rho for the plastic number rho, the 2-D generalisation of the golden ratio).
_GOLDEN_RATIO_FRAC = 0.6180339887498949
_PLASTIC_RATIO_FRAC = 0.7548776662466927
_RETRIES = 5


@dataclass(frozen=True)
class PosePlan:
    """Planned flange targets (the controller's belief poses) and what was dropped on the way."""

    flange_poses: list[Pose]
    tilt_deg: list[float]
    spin_deg: list[float]
    distance_mm: list[float]
    dropped: list[str] = field(default_factory=list)
    group: list[int] = field(default_factory=list)


def _in_image(points_C: F64, K: F64, dist: F64, size: tuple[int, int], margin_px: float) -> bool:
    if np.any(points_C[:, 2] <= 1.0):
        return False
    uv, _ = cv2.projectPoints(points_C.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    uv = uv.reshape(-1, 2)
    w, h = size
    return bool(
        np.all(uv[:, 0] >= margin_px) and np.all(uv[:, 0] <= w - 1 - margin_px)
        and np.all(uv[:, 1] >= margin_px) and np.all(uv[:, 1] <= h - 1 - margin_px)
    )


def _check_ranges(name: str, lo_hi: tuple[float, float], low: float = 0.0) -> tuple[float, float]:
    lo, hi = float(lo_hi[0]), float(lo_hi[1])
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo < low or hi < lo:
        raise ValueError(f"{name} must be (low, high) with {low:g} <= low <= high, got {lo_hi!r}")
    return lo, hi


def plan_board_views(
    T_B_P: ArrayLike,
    board_points_P: ArrayLike,
    T_H_C: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike,
    image_size: tuple[int, int],
    n_views: int,
    reach_check: ReachCheck,
    *,
    distance_mm: tuple[float, float] = (400.0, 470.0),
    tilt_deg: tuple[float, float] = (12.0, 35.0),
    spin_deg: float = 35.0,
    margin_px: float = 30.0,
    seed: int = 0,
) -> PosePlan:
    """Flange poses for ``n_views`` views of a board at ``T_B_P``.

    Args:
        T_B_P: the board frame (z into the board) in the base frame, as placed (roughly known).
        board_points_P: points (M, 3) that must stay in view: the board's outline with its border.
        T_H_C: the camera in the flange frame (nominal or calibrated).
        K, dist, image_size: the camera model used for the in-view check; image_size is (w, h).
        n_views: how many views to plan; the first looks straight at the board.
        reach_check: raises ValueError (e.g. the robot's ReachError) for a flange pose out of reach.
        distance_mm: range of camera-to-board-centre distances.
        tilt_deg: range of tilts of the optical axis away from the board normal.
        spin_deg: spins about the optical axis are spread over +-spin_deg.
        margin_px: keep the board this far inside the image.
        seed: the small random jitter of distance and position.
    """
    if n_views < 1:
        raise ValueError(f"n_views must be at least 1, got {n_views}")
    P = check_pose(T_B_P, "board pose T_B_P")
    X = check_pose(T_H_C, "camera mounting T_H_C")
    pts = np.asarray(board_points_P, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"board_points_P must have shape (M, 3), got {pts.shape}")
    d_lo, d_hi = _check_ranges("distance_mm", distance_mm, 1.0)
    t_lo, t_hi = _check_ranges("tilt_deg", tilt_deg)
    Km, Dm = np.asarray(K, dtype=float), np.asarray(dist, dtype=float).reshape(-1)
    rng = np.random.default_rng(seed)
    centre_P = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    pts_B = apply_pose(P, pts)
    X_inv = invert_pose(X)
    poses: list[Pose] = []
    tilts: list[float] = []
    spins: list[float] = []
    dists: list[float] = []
    dropped: list[str] = []
    k = 0
    max_candidates = 4 * n_views + 8
    while len(poses) < n_views and k < max_candidates:
        if k == 0:
            tilt0, phi, spin = 0.0, 0.0, 0.0
        else:
            frac = (k * _GOLDEN_RATIO_FRAC) % 1.0
            tilt0 = np.deg2rad(t_lo + (t_hi - t_lo) * frac)
            phi = k * GOLDEN_ANGLE_RAD
            spin = np.deg2rad(spin_deg) * np.sin(2.3999 * k + 0.7)
        d = d_lo + (d_hi - d_lo) * rng.random()
        lateral = rng.uniform(-5.0, 5.0, 2)
        reason = ""
        for attempt in range(_RETRIES):
            tilt = tilt0 * (0.8**attempt)
            axis = np.array([np.cos(phi), np.sin(phi), 0.0])
            R_P_C = axis_angle_to_matrix(axis * tilt) @ rot_z(spin)
            o_P = centre_P + np.array([lateral[0], lateral[1], 0.0]) - d * R_P_C[:, 2]
            T_B_C = P @ make_pose(R_P_C, o_P)
            pts_C = apply_pose(invert_pose(T_B_C), pts_B)
            if not _in_image(pts_C, Km, Dm, image_size, margin_px):
                reason = "board leaves the image"
                continue
            flange = T_B_C @ X_inv
            try:
                reach_check(flange)
            except ValueError as err:
                reason = f"out of reach ({err})"
                continue
            poses.append(flange)
            tilts.append(float(np.rad2deg(tilt)))
            spins.append(float(np.rad2deg(spin)))
            dists.append(float(d))
            reason = ""
            break
        if reason:
            dropped.append(f"candidate {k} (tilt {np.rad2deg(tilt0):.0f} deg about {np.rad2deg(phi) % 360:.0f} deg): {reason}")
        k += 1
    return PosePlan(poses, tilts, spins, dists, dropped)


@dataclass(frozen=True)
class _LaserPose:
    stand: int  # index into the wrist depths
    flange: Pose
    tilt_deg: float
    spin_deg: float
    distance_mm: float


def plan_laser_poses(
    T_B_W: ArrayLike,
    aim_W_mm: tuple[float, float],
    R_B_H_nominal: ArrayLike,
    r: ArrayLike,
    l: ArrayLike,  # noqa: E741
    n_poses: int,
    reach_check: ReachCheck,
    *,
    pivot_H_mm: ArrayLike = (0.0, 0.0, -250.0),
    standoff_mm: float = 350.0,
    wrist_depths_mm: Sequence[float] = tuple(float(v) for v in range(-300, 161, 20)),
    tilt_deg: tuple[float, float] = (20.0, 45.0),
    spin_deg: float = 90.0,
    range_mm: tuple[float, float] = (265.0, 435.0),
    on_wall: Callable[[F64], bool] | None = None,
) -> PosePlan:
    """Flange poses that show one flat wall to the laser from many directions and distances.

    Arm stands: the wrist centre (``pivot_H_mm`` in the flange frame, 250 mm behind the flange
    on an IRB 7600) is placed at one of ``wrist_depths_mm``, offsets along the wall normal from
    where it is when the untilted beam meets the aim point from ``standoff_mm`` (positive: away
    from the wall). At one stand only the wrist axes turn, so the arm's own position error, which
    depends on where the wrist centre is (axes 1-3), is one constant for all the stand's poses
    and goes into the stand's plane offset instead of into r (``PosePlan.group`` is the stand).

    Directions and distances: pose k tilts the beam away from the wall normal by an angle spread
    over ``tilt_deg`` (golden-ratio sequence) about an axis turning by the golden angle, spins it
    about itself by up to ``spin_deg``, and takes the stand whose beam length comes nearest a
    target distance that sweeps ``range_mm`` (a second low-discrepancy sequence, independent of
    the tilt). Every direction is thereby seen near and far. This matters because the wrist
    centre sits beside the beam, not on it: turning about it swings the laser's origin along the
    beam, so at one stand the distance follows the tilt, and r across the beam can only be told
    from l by the same tilt read at other distances. In the twin this design gives l about three
    times better than tilting at three fixed stands (see cellctl.calibration.laser).

    The poses are returned ordered by stand, so the arm moves to each stand once and the wrist
    does the rest, and within a stand from each pose to the nearest unvisited orientation (the
    wrist's turns dominate the collection time).

    Args:
        T_B_W: the wall frame (x, y in the wall, z into it) in the base frame, roughly known.
        aim_W_mm: where the untilted beam meets the wall (x, y in W): a patch of plain wall
            large enough for the tilted beams around it.
        R_B_H_nominal: a flange orientation whose nominal beam meets the wall nearly square-on.
        r, l: the laser's nominal origin and direction in the flange frame (CAD).
        n_poses: how many poses.
        reach_check: raises ValueError for a flange pose out of reach.
        pivot_H_mm: the wrist centre in the flange frame.
        standoff_mm: beam length to the aim point at wrist depth 0, untilted.
        wrist_depths_mm: the arm stands (at least one).
        tilt_deg: the range of beam tilts from the wall normal.
        spin_deg: the largest turn of the flange about the beam.
        range_mm: the nominal distance at every pose must lie in this range.
        on_wall: optional check that a spot (x, y in W) is on usable wall (not in the opening).
    """
    if n_poses < 1:
        raise ValueError(f"n_poses must be at least 1, got {n_poses}")
    W = check_pose(T_B_W, "wall frame T_B_W")
    t_lo, t_hi = _check_ranges("tilt_deg", tilt_deg)
    d_lo, d_hi = _check_ranges("range_mm", range_mm, 0.0)
    stands = [float(v) for v in wrist_depths_mm]
    if not stands:
        raise ValueError("wrist_depths_mm needs at least one arm stand")
    rv = np.asarray(r, dtype=float)
    lv = np.asarray(l, dtype=float) / np.linalg.norm(l)
    R0 = np.asarray(R_B_H_nominal, dtype=float)
    beam_B = R0 @ lv
    normal_B = W[:3, 2]
    if float(beam_B @ normal_B) < 0.9:
        raise ValueError("R_B_H_nominal must point the nominal beam at the wall (within about 25 deg of its normal)")
    aim_B = apply_pose(W, np.array([aim_W_mm[0], aim_W_mm[1], 0.0]))
    t0 = aim_B - R0 @ (rv + standoff_mm * lv)
    pivot0 = R0 @ np.asarray(pivot_H_mm, dtype=float) + t0
    e1 = np.cross(beam_B, W[:3, 1])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(beam_B, e1)
    W_inv = invert_pose(W)

    def candidate(tilt: float, phi: float, spin: float, depth: float) -> tuple[Pose, float] | str:
        axis = np.cos(phi) * e1 + np.sin(phi) * e2
        Q = axis_angle_to_matrix(axis * tilt) @ axis_angle_to_matrix(beam_B * spin)
        pivot = pivot0 - depth * normal_B
        R = Q @ R0
        t = pivot + Q @ (t0 - pivot0)
        origin = R @ rv + t
        direction = R @ lv
        denom = float(direction @ normal_B)
        dist = float((normal_B @ (aim_B - origin)) / denom) if denom > 1e-6 else np.inf
        if not d_lo <= dist <= d_hi:
            return f"nominal distance {dist:.0f} mm outside {d_lo:g}..{d_hi:g} mm"
        spot_W = apply_pose(W_inv, origin + dist * direction)[:2]
        if on_wall is not None and not on_wall(spot_W):
            return f"the beam would hit ({spot_W[0]:.0f}, {spot_W[1]:.0f}) mm in the wall frame, not plain wall"
        flange = make_pose(R, t)
        try:
            reach_check(flange)
        except ValueError as err:
            return f"out of reach ({err})"
        return flange, dist

    planned: list[_LaserPose] = []
    dropped: list[str] = []
    m = 0
    while len(planned) < n_poses and m < 4 * n_poses + 8:
        tilt0 = np.deg2rad(t_lo + (t_hi - t_lo) * ((m * _GOLDEN_RATIO_FRAC + 0.3) % 1.0))
        phi = m * GOLDEN_ANGLE_RAD
        spin = np.deg2rad(spin_deg) * np.sin(2.3999 * m + 0.4)
        target = d_lo + (d_hi - d_lo) * ((m * _PLASTIC_RATIO_FRAC + 0.1) % 1.0)
        reason = ""
        for attempt in range(_RETRIES):
            tilt = tilt0 * (0.85**attempt)
            options: list[tuple[float, int, Pose, float]] = []
            for k, depth in enumerate(stands):
                found = candidate(tilt, phi, spin, depth)
                if isinstance(found, str):
                    reason = found
                else:
                    options.append((abs(found[1] - target), k, found[0], found[1]))
            if options:
                _, k, flange, dist = min(options, key=lambda o: o[0])
                planned.append(_LaserPose(k, flange, float(np.rad2deg(tilt)), float(np.rad2deg(spin)), dist))
                reason = ""
                break
        if reason:
            dropped.append(f"pose {m} (tilt {np.rad2deg(tilt0):.0f} deg): {reason}")
        m += 1
    planned = _visit_order(planned, stands)
    return PosePlan(
        [p.flange for p in planned], [p.tilt_deg for p in planned], [p.spin_deg for p in planned],
        [p.distance_mm for p in planned], dropped, [p.stand for p in planned],
    )


def _visit_order(planned: list[_LaserPose], stands: Sequence[float]) -> list[_LaserPose]:
    """Stand by stand (nearest to the wall first), each stand's poses by greedy nearest rotation."""
    ordered: list[_LaserPose] = []
    for k in sorted({p.stand for p in planned}, key=lambda k: stands[k]):
        left = [p for p in planned if p.stand == k]
        while left:
            if ordered:
                R_prev = ordered[-1].flange[:3, :3]
                turn = [rotation_angle_between(R_prev, p.flange[:3, :3]) for p in left]
                ordered.append(left.pop(int(np.argmin(turn))))
            else:
                ordered.append(left.pop(0))
    return ordered
