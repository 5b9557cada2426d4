"""Smooth, bounded random fields: the shape of fixed (systematic) errors in the twin.

A systematic error, such as a robot's absolute-accuracy error, is the same every time the same
pose is visited, changes smoothly from pose to pose, and has a known worst case. A sum of a few
plane waves with random directions, wavelengths and phases has all three properties: it is
infinitely smooth, its value is bounded by the sum of the amplitudes, and its slope by the sum of
amplitude times wavenumber.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


class SmoothRandomField:
    """f(x) = sum_k a_k sin(w_k . x + phi_k), mapping R^n to R^m, with |f(x)| <= bound everywhere.

    Wavelengths are drawn in [min_wavelength, 2 min_wavelength], directions uniformly on the
    sphere, and the amplitude vectors are scaled so that sum_k |a_k| equals ``bound``: the bound
    holds exactly, and the field's peak over a region a few wavelengths wide comes close to it.

    Args:
        rng: the generator to draw the field from (the field is fixed once drawn).
        bound: the largest magnitude the field may take (0 gives the zero field).
        dim_in, dim_out: input and output dimensions.
        min_wavelength: the shortest wavelength, in the input's units.
        n_modes: the number of plane waves.
    """

    def __init__(
        self,
        rng: np.random.Generator,
        bound: float,
        *,
        dim_in: int = 3,
        dim_out: int = 3,
        min_wavelength: float,
        n_modes: int = 4,
    ) -> None:
        if not np.isfinite(bound) or bound < 0:
            raise ValueError(f"bound must be a finite non-negative number, got {bound}")
        if not np.isfinite(min_wavelength) or min_wavelength <= 0:
            raise ValueError(f"min_wavelength must be a positive number, got {min_wavelength}")
        if n_modes < 1 or dim_in < 1 or dim_out < 1:
            raise ValueError("n_modes, dim_in and dim_out must be at least 1")
        # Draw everything even for a zero bound, so the stream is consumed the same either way.
        directions = rng.normal(size=(n_modes, dim_in))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        wavelengths = min_wavelength * rng.uniform(1.0, 2.0, n_modes)
        self._omega = directions * (2.0 * np.pi / wavelengths)[:, None]
        self._phase = rng.uniform(0.0, 2.0 * np.pi, n_modes)
        amplitudes = rng.normal(size=(n_modes, dim_out))
        amplitudes *= rng.uniform(0.5, 1.0, n_modes)[:, None] / np.linalg.norm(amplitudes, axis=1, keepdims=True)
        self._amp = amplitudes * (bound / float(np.sum(np.linalg.norm(amplitudes, axis=1))))
        self.bound = float(bound)
        self.dim_in = dim_in
        self.dim_out = dim_out

    @property
    def lipschitz(self) -> float:
        """An upper bound on |f(x) - f(y)| / |x - y| (the field's steepest slope)."""
        return float(np.sum(np.linalg.norm(self._amp, axis=1) * np.linalg.norm(self._omega, axis=1)))

    def __call__(self, x: ArrayLike) -> NDArray[np.float64]:
        """The field at points ``x`` of shape (dim_in,) or (N, dim_in)."""
        X = np.asarray(x, dtype=float)
        if X.shape[-1] != self.dim_in or X.ndim > 2:
            raise ValueError(f"field input must have shape ({self.dim_in},) or (N, {self.dim_in}), got {X.shape}")
        return np.sin(X @ self._omega.T + self._phase) @ self._amp
