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

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.inspection.flush_outliers import RejectedSpot, UnverifiableSpot, check_spots, tilt_setting_spots

DEFAULT_OUTLIER_MM = 0.1  # as process.inspect.flush_outlier_mm's default


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
        rejected: the spots left out as off their neighbours (named as fit_flush's ``spots``, else by input row).
        unverifiable: the spots their neighbours cannot check (a lone far spot that sets a tilt).
        unreliable: why the figures should not feed the quality loop, or None.
    """

    dz_mm: float
    drx_rad: float
    dry_rad: float
    flush_mm: tuple[float, ...]
    glass_rms_mm: float
    wall_rms_mm: float
    dz_sigma_mm: float
    rejected: tuple[RejectedSpot, ...] = ()
    unverifiable: tuple[UnverifiableSpot, ...] = ()
    unreliable: str | None = None


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


def fit_flush(
    glass_T: ArrayLike, wall_T: ArrayLike, *, max_rms_mm: float, outlier_mm: float | None = DEFAULT_OUTLIER_MM,
    min_spots: int = 3, spots: Sequence[int] | None = None,
) -> FlushResult:
    """The glass's plane against the wall's from laser points in the workpiece frame (x, y, z; mm).

    Where glass and wall come in pairs (row k of each: one location) and ``outlier_mm`` is given, a
    spot whose step is off the others' (:mod:`cellctl.inspection.flush_outliers`, ``outlier_mm``: the
    floor of the limit) is left out and named (row k as ``spots[k]``, default k). Raises FlushError when
    a fit has too few points (fewer than ``min_spots`` pairs left), the spots are collinear, or a
    residual exceeds ``max_rms_mm``.
    """
    g = np.asarray(glass_T, dtype=float)
    w = np.asarray(wall_T, dtype=float)
    rejected: list[RejectedSpot] = []
    unverifiable: list[UnverifiableSpot] = []
    keep = np.arange(len(g))
    paired = g.shape == w.shape and g.ndim == 2 and g.shape[1] == 3 and bool(np.all(np.isfinite(g)) and np.all(np.isfinite(w)))
    if outlier_mm is not None and paired:
        kept, rejected, unverifiable = check_spots(g, w, floor_mm=outlier_mm)
        keep = np.array(kept, dtype=int)
        if spots is not None:
            rejected = [replace(r, index=int(spots[r.index])) for r in rejected]
            unverifiable = [replace(u, index=int(spots[u.index])) for u in unverifiable]
        if len(keep) < min_spots:
            raise FlushError(
                f"only {len(keep)} flush spots are left after leaving out {_named(rejected)} (at least {min_spots} "
                "needed): check those spots for a seal, an edge or a reflection under the beam"
            )
    cg, rms_g, cov_g = _height_plane(g[keep] if rejected else g, "glass")
    cw, rms_w, cov_w = _height_plane(w[keep] if rejected else w, "wall")
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
        rejected=tuple(rejected),
        unverifiable=tuple(unverifiable),
    )


def _named(rejected: list[RejectedSpot]) -> str:
    """The rejected spots as ``spot 3 (glass, +0.300 mm)`` items."""
    return ", ".join(f"spot {r.index} ({r.surface}, {r.off_mm:+.3f} mm)" for r in rejected) or "none"


def on_layout(flush: FlushResult, used: Sequence[int], layout_xy: ArrayLike) -> FlushResult:
    """The result marked unreliable when a spot that alone sets a tilt in the layout (its far spots) is not among
    the ``used`` ones (its reading missing) or was left out as an outlier."""
    kept = {int(i) for i in used} - {r.index for r in flush.rejected}
    lost = [i for i in tilt_setting_spots(np.asarray(layout_xy, dtype=float)) if i not in kept]
    if not lost:
        return flush
    why = f"the flush spots {lost}, which set the tilt, are missing or left out: dRx and dRy rest on the other spots alone"
    return replace(flush, unreliable=why)
