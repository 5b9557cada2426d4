"""Laser spots to 3-D points (paper eq. 1) and planning where to put them."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.align.errors import AlignmentError
from cellctl.geometry.aiming import flange_pose_at_spot
from cellctl.geometry.pose import Pose, apply_pose

UNIT_TOLERANCE = 1e-6


def check_laser_ray(r: ArrayLike, l: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # noqa: E741
    """Return (r, l) as arrays after checking r is finite and l a finite unit vector."""
    rv = np.asarray(r, dtype=float)
    lv = np.asarray(l, dtype=float)
    if rv.shape != (3,) or not np.all(np.isfinite(rv)):
        raise AlignmentError(f"laser origin r must be 3 finite numbers (mm in the flange frame), got {r!r}")
    if lv.shape != (3,) or not np.all(np.isfinite(lv)):
        raise AlignmentError(f"laser direction l must be 3 finite numbers, got {l!r}")
    norm = float(np.linalg.norm(lv))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise AlignmentError(
            f"laser direction l has length {norm:.9f}, not 1; use the calibrated unit vector "
            "(divide l by its length if it was rounded)"
        )
    return rv, lv


def laser_points(
    T_X_H: ArrayLike,
    r: ArrayLike,
    l: ArrayLike,  # noqa: E741
    distances_mm: ArrayLike,
    range_mm: tuple[float, float] | None = None,
) -> NDArray[np.float64]:
    """Points hit by the laser, in frame X (paper eq. 1: P_i = T_X_H @ (r + d_i l)).

    Args:
        T_X_H: (N, 4, 4) flange poses at the moments of the readings, in frame X (usually B).
        r: laser origin in the flange frame (mm).
        l: unit laser direction in the flange frame.
        distances_mm: (N,) measured distances along l from r.
        range_mm: the sensor's (min, max) measuring range; a distance outside it is refused.

    Returns:
        (N, 3) points in frame X.
    """
    poses = np.asarray(T_X_H, dtype=float)
    d = np.asarray(distances_mm, dtype=float).reshape(-1)
    rv, lv = check_laser_ray(r, l)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise AlignmentError(f"flange poses must have shape (N, 4, 4), got {poses.shape}")
    if poses.shape[0] != d.shape[0]:
        raise AlignmentError(f"{poses.shape[0]} flange poses but {d.shape[0]} distances; give one pose per reading")
    if not np.all(np.isfinite(poses)):
        bad = np.flatnonzero(~np.all(np.isfinite(poses), axis=(1, 2))).tolist()
        raise AlignmentError(f"flange poses {bad} contain NaN or infinite values")
    if not np.all(np.isfinite(d)):
        raise AlignmentError(f"distances {np.flatnonzero(~np.isfinite(d)).tolist()} are not finite numbers")
    if range_mm is not None:
        lo, hi = range_mm
        out = np.flatnonzero((d < lo) | (d > hi))
        if out.size:
            raise AlignmentError(
                f"distances {[(int(i), round(float(d[i]), 3)) for i in out]} (index, mm) lie outside the "
                f"sensor's range {lo:g}..{hi:g} mm; move those spots to bring the wall into range"
            )
    local = rv[None, :] + d[:, None] * lv[None, :]  # eq. 1 in the flange frame
    return np.einsum("nij,nj->ni", poses[:, :3, :3], local) + poses[:, :3, 3]


def laser_origins(T_X_H: ArrayLike, r: ArrayLike) -> NDArray[np.float64]:
    """Where the laser leaves the sensor for each flange pose, in frame X."""
    poses = np.asarray(T_X_H, dtype=float)
    return np.einsum("nij,j->ni", poses[:, :3, :3], np.asarray(r, dtype=float)) + poses[:, :3, 3]


def flange_pose_for_spot(
    spot_X: ArrayLike, R_X_H: ArrayLike, r: ArrayLike, l: ArrayLike, standoff_mm: float  # noqa: E741
) -> Pose:
    """The flange pose, with orientation ``R_X_H``, that puts the laser spot on ``spot_X`` at ``standoff_mm``.

    Solves eq. 1 backwards: p_H = spot - R (r + standoff * l).
    """
    rv, lv = check_laser_ray(r, l)
    return flange_pose_at_spot(spot_X, R_X_H, rv, lv, standoff_mm)


def plan_spot_poses(
    T_X_T0: ArrayLike,
    spots_T0_mm: ArrayLike,
    R_X_H: ArrayLike,
    r: ArrayLike,
    l: ArrayLike,  # noqa: E741
    standoff_mm: float,
) -> NDArray[np.float64]:
    """Flange poses (N, 4, 4) aiming the laser at spots given as (x, y) on the taught wall frame T0."""
    spots = np.asarray(spots_T0_mm, dtype=float)
    if spots.ndim != 2 or spots.shape[1] != 2:
        raise AlignmentError(f"spots must have shape (N, 2) (x, y on the wall in mm), got {spots.shape}")
    on_wall = apply_pose(T_X_T0, np.column_stack([spots, np.zeros(len(spots))]))
    return np.stack([flange_pose_for_spot(p, R_X_H, r, l, standoff_mm) for p in on_wall])


def sweep_route(corners: Sequence[ArrayLike], l: ArrayLike, approach_mm: float, *, beam_moves: int) -> list[NDArray[np.float64]]:
    """A sweep's flange poses in order: ``beam_moves`` moves along the beam l (flange frame) by ``approach_mm``
    at the first corner, starting from out (3: in, out and in, which time the laser; 1: in, which checks a
    known latency; 0: none), then the corners."""
    if beam_moves not in (0, 1, 3):
        raise ValueError(f"beam_moves must be 0, 1 or 3 (none, in, or in-out-in), got {beam_moves!r}")
    first = np.asarray(corners[0], dtype=float)
    rest = [np.asarray(T, dtype=float) for T in corners[1:]]
    if not beam_moves:
        return [first, *rest]
    back = first.copy()
    back[:3, 3] -= (first[:3, :3] @ np.asarray(l, dtype=float)) * approach_mm
    return [back, *[first, back] * (beam_moves // 2), first, *rest]
