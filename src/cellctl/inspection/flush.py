"""Flush: where the installed glass's surface lies against the wall, from laser spots on both.

Each flush location gives a laser point on the glass's outer surface and one on the wall just
across the opening's edge (paper eq. 1, ``P = T_B_H @ (r + d l)``). Expressed in the measured
workpiece frame, each set is fitted with a height plane ``z = a + b x + c y``; the glass's
plane relative to the wall's is the install's out-of-plane deviation: at T's origin
``dZ = a_g - a_w``, and with E = Rz Ry Rx (eq. 13) a glass point (x, y, 0) lands at height
``-Ry x + Rx y`` to first order, so ``dRx = c_g - c_w`` and ``dRy = -(b_g - b_w)``.

A glass spot and its wall spot are read from neighbouring robot poses, so the robot's slowly
varying accuracy error and the laser's mounting error cancel in the difference; what is left is
the robot's repeatability per stop, which the number of locations averages down.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


class FlushError(ValueError):
    """The flush cannot be measured from these points (too few, or the surfaces are not planes)."""


@dataclass(frozen=True)
class FlushResult:
    """The glass's surface against the wall's, in the measured workpiece frame.

    Attributes:
        dz_mm: the glass surface's height over the wall plane at T's origin (+ = into the wall).
        drx_rad, dry_rad: the glass plane's tilt against the wall's (XYZ fixed angles, eq. 13).
        flush_mm: at each glass spot (on the move: each edge crossing), its height over the wall there (the flush a gauge shows).
        glass_rms_mm, wall_rms_mm: the residuals of the two plane fits.
        dz_sigma_mm: the 1-sigma of dz predicted from the fits' residuals and the spots' layout.
    """

    dz_mm: float
    drx_rad: float
    dry_rad: float
    flush_mm: tuple[float, ...]
    glass_rms_mm: float
    wall_rms_mm: float
    dz_sigma_mm: float


def _height_plane(points: NDArray[np.float64], what: str) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:
    """Least-squares ``z = a + b x + c y``: the coefficients, the RMS residual and (A^T A)^-1."""
    if points.ndim != 2 or points.shape[1] != 3:
        raise FlushError(f"{what} points must have shape (N, 3), got {points.shape}")
    if len(points) < 3:
        raise FlushError(f"{len(points)} {what} points; the plane needs at least 3")
    if not np.all(np.isfinite(points)):
        raise FlushError(f"{what} points contain NaN or infinite values")
    A = np.column_stack([np.ones(len(points)), points[:, 0], points[:, 1]])
    if np.linalg.matrix_rank(A) < 3:
        raise FlushError(f"the {what} spots lie on one line; spread them in x and y to fix the tilt")
    coef, *_ = np.linalg.lstsq(A, points[:, 2], rcond=None)
    residual = points[:, 2] - A @ coef
    dof = max(len(points) - 3, 1)
    rms = float(np.sqrt(np.sum(residual**2) / dof)) if len(points) > 3 else 0.0
    return coef, rms, np.linalg.inv(A.T @ A)


def fit_flush(glass_T: ArrayLike, wall_T: ArrayLike, *, max_rms_mm: float) -> FlushResult:
    """The glass's plane against the wall's from laser points in the workpiece frame (x, y, z; mm).

    Raises FlushError when a fit has too few points, the spots are collinear, or a residual
    exceeds ``max_rms_mm`` (a spot on the gap's edge, a reading off another surface).
    """
    g = np.asarray(glass_T, dtype=float)
    w = np.asarray(wall_T, dtype=float)
    cg, rms_g, cov_g = _height_plane(g, "glass")
    cw, rms_w, cov_w = _height_plane(w, "wall")
    for what, rms in (("glass", rms_g), ("wall", rms_w)):
        if rms > max_rms_mm:
            raise FlushError(
                f"the {what} spots do not lie on one plane (RMS {rms:.3f} mm > {max_rms_mm:g} mm): a spot on an edge "
                "or a reading off another surface; check the flush spots against the opening and the glass"
            )
    wall_at_glass = cw[0] + cw[1] * g[:, 0] + cw[2] * g[:, 1]
    # Predicted spread of dz at the origin: each fit's variance of its intercept, from its residual.
    sigma = float(np.sqrt(rms_g**2 * cov_g[0, 0] + rms_w**2 * cov_w[0, 0]))
    return FlushResult(
        dz_mm=float(cg[0] - cw[0]),
        drx_rad=float(cg[2] - cw[2]),
        dry_rad=float(-(cg[1] - cw[1])),
        flush_mm=tuple(float(v) for v in g[:, 2] - wall_at_glass),
        glass_rms_mm=rms_g,
        wall_rms_mm=rms_w,
        dz_sigma_mm=sigma,
    )
