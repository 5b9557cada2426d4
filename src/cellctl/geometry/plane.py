"""Least-squares plane through 3-D points: the smallest eigenvector of the scatter matrix.

Paper section 3.1: minimise sum (A x_i + B y_i + C z_i - D)^2 subject to A^2 + B^2 + C^2 = 1
(eq. 3). The Lagrange conditions (eq. 4-5) give D from the centroid, and after centring (eq. 7-9)
the normal (A, B, C) is an eigenvector of the 3x3 centred scatter matrix R_c (eq. 10); the
eigenvector of the smallest eigenvalue minimises the sum (eq. 11).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


class PlaneFitError(ValueError):
    """The points do not define a plane (too few, non-finite, coincident or collinear)."""


@dataclass(frozen=True)
class PlaneFit:
    """A fitted plane ``normal . p = offset`` and how well the points support it.

    Attributes:
        normal: unit normal (A, B, C) of eq. 2.
        offset: D of eq. 2, the signed distance of the origin's foot point along ``normal`` (mm).
        centroid: mean of the points (mm); the plane passes through it (eq. 5).
        eigenvalues: eigenvalues of the centred scatter matrix R_c (eq. 10), ascending (mm^2).
        eigenvectors: matching unit eigenvectors as columns; column 0 is ``normal``.
        residuals: signed distances of the points from the plane (mm).
    """

    normal: NDArray[np.float64]
    offset: float
    centroid: NDArray[np.float64]
    eigenvalues: NDArray[np.float64]
    eigenvectors: NDArray[np.float64]
    residuals: NDArray[np.float64]

    @property
    def rms(self) -> float:
        """Root-mean-square distance of the points from the plane (mm)."""
        return float(np.sqrt(np.mean(self.residuals**2)))

    @property
    def max_residual(self) -> float:
        """Largest absolute distance of a point from the plane (mm)."""
        return float(np.max(np.abs(self.residuals)))

    @property
    def planarity(self) -> float:
        """lambda_min / lambda_mid: near 0 for points on a plane, near 1 when no plane is preferred."""
        return float(self.eigenvalues[0] / self.eigenvalues[1])

    @property
    def collinearity(self) -> float:
        """lambda_mid / lambda_max: near 0 when the points lie on a line (the plane is undetermined)."""
        return float(self.eigenvalues[1] / self.eigenvalues[2])

    def flipped(self) -> "PlaneFit":
        """The same plane with the normal reversed (offset negated)."""
        E = self.eigenvectors.copy()
        E[:, 0] = -E[:, 0]
        return PlaneFit(-self.normal, -self.offset, self.centroid, self.eigenvalues, E, -self.residuals)

    def distance(self, points: ArrayLike) -> NDArray[np.float64]:
        """Signed distance (mm) of points from the plane, positive along ``normal``."""
        return np.asarray(points, dtype=float) @ self.normal - self.offset


def fit_plane(points: ArrayLike, min_collinearity: float = 1e-6) -> PlaneFit:
    """Fit a plane to N >= 3 points (paper eq. 2 to 11).

    Args:
        points: (N, 3) coordinates in mm.
        min_collinearity: the smallest acceptable lambda_mid / lambda_max; below it the points are
            refused as collinear because the plane's tilt about their line is undetermined.

    Raises:
        PlaneFitError: fewer than 3 points, non-finite values, coincident or collinear points.
    """
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3:
        raise PlaneFitError(f"points must have shape (N, 3), got {P.shape}")
    n = P.shape[0]
    if n < 3:
        raise PlaneFitError(f"a plane needs at least 3 points, got {n}; measure more laser spots")
    bad = ~np.all(np.isfinite(P), axis=1)
    if bad.any():
        raise PlaneFitError(f"points {np.flatnonzero(bad).tolist()} contain NaN or infinite values")
    centroid = P.mean(axis=0)  # eq. 5, 7
    V = P - centroid
    Rc = V.T @ V  # eq. 10: the centred scatter matrix
    eigenvalues, eigenvectors = np.linalg.eigh(Rc)  # ascending; eq. 11
    eigenvalues = np.clip(eigenvalues, 0.0, None)
    scale = float(np.max(np.abs(V))) if n else 0.0
    if eigenvalues[2] <= (1e-9 * max(scale, 1.0)) ** 2 * n:
        raise PlaneFitError(
            f"the {n} points coincide (spread {np.sqrt(eigenvalues[2] / n):.3g} mm); "
            "move the laser spots apart"
        )
    collinearity = eigenvalues[1] / eigenvalues[2]
    if collinearity < min_collinearity:
        raise PlaneFitError(
            f"the {n} points are collinear (lambda_mid/lambda_max = {collinearity:.3g} < "
            f"{min_collinearity:g}); place at least one spot off the line of the others"
        )
    normal = eigenvectors[:, 0]
    offset = float(normal @ centroid)  # eq. 5: D = mean of A x + B y + C z
    residuals = P @ normal - offset
    return PlaneFit(normal, offset, centroid, eigenvalues, eigenvectors, residuals)
