"""Flange orientation that puts the camera's optical axis along the wall normal (paper section 3.2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from cellctl.align.errors import AlignmentError
from cellctl.geometry.rotation import (
    angle_between_vectors,
    matrix_to_xyz_fixed,
    minimal_rotation,
    xyz_fixed_to_matrix,
)


@dataclass(frozen=True)
class FlangeOrientation:
    """A solved flange orientation.

    Attributes:
        R_B_H: the new flange rotation in the base frame.
        angles_rad: its XYZ fixed angles (alpha, beta, gamma) of eq. 13.
        axis_error_rad: angle between the camera's z axis under ``R_B_H`` and the normal.
        method: "lm" (eq. 13 by Levenberg-Marquardt) or "minimal" (closed form).
        iterations: function evaluations the solver used (0 for the closed form).
    """

    R_B_H: NDArray[np.float64]
    angles_rad: tuple[float, float, float]
    axis_error_rad: float
    method: str
    iterations: int = 0


def _check_inputs(R_B_H: ArrayLike, z_C_in_H: ArrayLike, normal: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    R = np.asarray(R_B_H, dtype=float)
    a = np.asarray(z_C_in_H, dtype=float)
    n = np.asarray(normal, dtype=float)
    for name, v in (("camera z axis in H", a), ("wall normal", n)):
        if v.shape != (3,) or not np.all(np.isfinite(v)) or abs(np.linalg.norm(v) - 1.0) > 1e-9:
            raise AlignmentError(f"{name} must be a finite unit 3-vector, got {v!r}")
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise AlignmentError("current flange rotation must be a finite 3x3 matrix")
    return R, a, n


def solve_orientation_lm(
    R_B_H_current: ArrayLike, z_C_in_H: ArrayLike, normal: ArrayLike
) -> FlangeOrientation:
    """Solve eq. 13, ``[A B C]^T = R(alpha, beta, gamma) [a13 a23 a33]^T``, by Levenberg-Marquardt.

    As the paper does, the iteration starts from the current flange angles, so of the one-parameter
    family of solutions (any spin about the normal) it settles on one close to the current pose.

    Args:
        R_B_H_current: the flange rotation when the last spot was measured.
        z_C_in_H: the camera's z axis in the flange frame, the third column of R_H_C (eq. 12).
        normal: the wall's unit normal, pointing into the wall, in the base frame.
    """
    R0, a, n = _check_inputs(R_B_H_current, z_C_in_H, normal)
    x0 = np.array(matrix_to_xyz_fixed(R0))

    def residual(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return xyz_fixed_to_matrix(*x) @ a - n  # eq. 13

    sol = least_squares(residual, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=2000)
    R = xyz_fixed_to_matrix(*sol.x)
    err = angle_between_vectors(R @ a, n)
    if not sol.success or err > 1e-9:
        raise AlignmentError(
            f"Levenberg-Marquardt did not solve eq. 13 (axis error {err:.3g} rad, {sol.message}); "
            "use the closed-form orientation"
        )
    alpha, beta, gamma = (float(v) for v in sol.x)
    return FlangeOrientation(R, (alpha, beta, gamma), err, "lm", int(sol.nfev))


def solve_orientation_minimal(
    R_B_H_current: ArrayLike, z_C_in_H: ArrayLike, normal: ArrayLike
) -> FlangeOrientation:
    """The smallest rotation of the flange that turns the camera's z axis onto the normal.

    No spin about the normal is added, so the image keeps its roll relative to the wall.
    """
    R0, a, n = _check_inputs(R_B_H_current, z_C_in_H, normal)
    R = minimal_rotation(R0 @ a, n) @ R0
    err = angle_between_vectors(R @ a, n)
    return FlangeOrientation(R, matrix_to_xyz_fixed(R), err, "minimal", 0)
