"""The twin's Keyence LK-G500: a ray cast from the true flange pose, with the sensor's errors.

The beam leaves at r along l, fixed in the flange frame H (paper eq. 19), and meets the car-body
wall. ``d_reported = d_true + linearity(d_true) + noise`` (mm):

- linearity: a smooth systematic curve over the range, fixed per sensor (from its seed), at most
  +-``linearity_fraction_fs`` of full scale (paper: +-0.02 % of 200 mm), with no gain or offset part;
- noise: white Gaussian repeatability, ``noise_mm`` one sigma, per reading.

Without a distance the reading carries the LK-G status: nearer than the range OVER_RANGE_NEAR
(``-FFFFFFF``), beyond it OVER_RANGE_FAR (``+FFFFFFF``), no surface (the beam passes through the
opening) ``no_return_status``; NO_VALUE (``XXXXXXXX``) comes from the device layer.

An installed glass (cellctl.sim.glass) is a surface too: the beam meets its outer surface where
it lies inside the glass's outline, if that comes before the wall. Its front reflection is weak,
so a reading there gets the glass's noise (``laser_noise_mm``) instead of the head's, and with
``laser_dropout_probability`` comes back without a value (NO_VALUE, as the LK-G's ``XXXXXXXX``
for too little light). The gap between the glass's and the opening's edges returns nothing, as
the opening does. Those draws come from their own stream, so the wall's noise stream is the same
with or without a glass.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.config.sim import LaserSimConfig
from cellctl.geometry.pose import check_pose
from cellctl.ports import LaserStatus
from cellctl.sim.glass import InstalledGlass
from cellctl.sim.streams import LASER_GLASS, LASER_LINEARITY, LASER_NOISE, rng_stream
from cellctl.sim.world import World

# Harmonics in the linearity curve: its shape varies over about a third of the range at most.
LINEARITY_HARMONICS = 3
# Grid used once to remove the straight-line part and to scale the curve to its bound.
LINEARITY_GRID = 4097

NO_RETURN_STATUS = {
    "over_range_far": LaserStatus.OVER_RANGE_FAR,
    "over_range_near": LaserStatus.OVER_RANGE_NEAR,
    "no_value": LaserStatus.NO_VALUE,
}


class LaserModel:
    """The physics of one LK-G500 head on the fixture.

    Args:
        config: the laser's section of the twin's configuration (mounting, range, error sources).
        seed: the cell's seed; linearity and noise draw from their own streams.
    """

    def __init__(self, config: LaserSimConfig, seed: int) -> None:
        self.config = config
        self.r = config.r
        self.l = config.l  # noqa: E741 - the paper's name for the laser direction
        lin_rng = rng_stream(seed, LASER_LINEARITY)
        k = np.arange(1, LINEARITY_HARMONICS + 1)
        self._lin_amp = lin_rng.normal(size=LINEARITY_HARMONICS) / k
        self._lin_phase = lin_rng.uniform(0.0, 2.0 * np.pi, LINEARITY_HARMONICS)
        self._lin_k = k
        u = np.linspace(0.0, 1.0, LINEARITY_GRID)
        raw = self._lin_raw(u)
        self._lin_slope, self._lin_offset = np.polyfit(u, raw, 1)
        peak = float(np.max(np.abs(raw - (self._lin_slope * u + self._lin_offset))))
        self.linearity_bound_mm = config.linearity_fraction_fs * config.full_scale_mm
        self._lin_scale = self.linearity_bound_mm / peak if peak > 0 else 0.0
        self._noise_rng = rng_stream(seed, LASER_NOISE)
        self._glass_rng = rng_stream(seed, LASER_GLASS)

    def _lin_raw(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.sin(np.pi * np.multiply.outer(u, self._lin_k) + self._lin_phase) @ self._lin_amp

    def linearity_error(self, distance_mm: ArrayLike) -> NDArray[np.float64]:
        """The fixed linearity deviation (mm) at true distance(s) ``distance_mm``.

        Smooth over the range and within +-linearity_bound_mm; held at its end values outside it.
        """
        d = np.asarray(distance_mm, dtype=float)
        u = np.clip((d - self.config.range_min_mm) / self.config.full_scale_mm, 0.0, 1.0)
        return self._lin_scale * (self._lin_raw(u) - (self._lin_slope * u + self._lin_offset))

    def beam(self, T_B_H_true: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The beam's origin and unit direction in the base frame for a true flange pose."""
        T = check_pose(T_B_H_true, "true flange pose")
        return T[:3, :3] @ self.r + T[:3, 3], T[:3, :3] @ self.l

    def true_distance(self, T_B_H_true: ArrayLike, world: World, glass: InstalledGlass | None = None) -> float | None:
        """Distance from r along l to the wall or the glass, or None if the beam finds neither."""
        return self._hit(T_B_H_true, world, glass)[0]

    def _hit(self, T_B_H_true: ArrayLike, world: World, glass: InstalledGlass | None) -> tuple[float | None, bool]:
        """The nearest surface along the beam: (distance or None, whether it is the glass)."""
        origin, direction = self.beam(T_B_H_true)
        d, _ = world.ray_hit(origin, direction)
        if glass is not None:
            d_glass = glass.ray_hit(origin, direction)
            if d_glass is not None and (d is None or d_glass < d):
                return d_glass, True
        return d, False

    def reading(
        self, T_B_H_true: ArrayLike, world: World, glass: InstalledGlass | None = None
    ) -> tuple[LaserStatus, float | None]:
        """One reading at a true flange pose: (status, distance in mm or None), with ``glass`` installed if given.

        One noise value is drawn per reading whatever its outcome, so the noise stream advances
        with the number of readings only; with a glass, the glass stream draws its noise and
        dropout per reading the same way.
        """
        noise = float(self._noise_rng.normal()) * self.config.noise_mm
        on_glass = None
        if glass is not None:
            z, u = self._glass_rng.normal(), self._glass_rng.random()
            on_glass = (float(z) * glass.laser_noise_mm, float(u) < glass.laser_dropout_probability)
        d, hit_glass = self._hit(T_B_H_true, world, glass)
        if d is None:
            return NO_RETURN_STATUS[self.config.no_return_status], None
        if hit_glass:
            assert on_glass is not None
            noise, dropped = on_glass
            if dropped:
                return LaserStatus.NO_VALUE, None
        measured = d + float(self.linearity_error(d)) + noise
        if measured < self.config.range_min_mm:
            return LaserStatus.OVER_RANGE_NEAR, None
        if measured > self.config.range_max_mm:
            return LaserStatus.OVER_RANGE_FAR, None
        return LaserStatus.OK, measured
