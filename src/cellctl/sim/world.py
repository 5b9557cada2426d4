"""The simulated car-body wall with its window opening, and the car body's random posture."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.config.sim import WorldConfig
from cellctl.geometry.pose import Pose, apply_pose, invert_pose, make_pose
from cellctl.geometry.rotation import xyz_fixed_to_matrix


@dataclass(frozen=True)
class World:
    """One placement of the car body.

    Attributes:
        T_B_T: the true workpiece frame at the opening's upper-right corner (see WorldConfig).
        width_mm, height_mm, corner_radius_mm: the opening, a rounded rectangle in T's x-y plane
            occupying x in [-width, 0], y in [0, height].
        surface_seed: seeds the drawing of this car body's surface around the opening (its
            bands, marks and dirt: cellctl.sim.surface), so every frame of it shows the same one;
            sample_world derives it from the placement. The same body moved keeps it
            (``dataclasses.replace(world, T_B_T=...)``).
    """

    T_B_T: Pose
    width_mm: float
    height_mm: float
    corner_radius_mm: float
    surface_seed: int = 0

    @property
    def normal_B(self) -> NDArray[np.float64]:
        """Unit wall normal into the wall, in the base frame."""
        return self.T_B_T[:3, 2].copy()

    @property
    def offset_B(self) -> float:
        """D of the wall plane normal . p = D in the base frame."""
        return float(self.normal_B @ self.T_B_T[:3, 3])

    def in_opening(self, xy_T: ArrayLike) -> NDArray[np.bool_]:
        """Whether points (x, y) in T lie inside the opening (no wall there)."""
        p = np.atleast_2d(np.asarray(xy_T, dtype=float))
        # Centre the rounded rectangle and use its signed distance.
        half = np.array([self.width_mm / 2.0, self.height_mm / 2.0])
        q = np.abs(p - np.array([-half[0], half[1]])) - (half - self.corner_radius_mm)
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(np.max(q, axis=1), 0.0)
        return outside < self.corner_radius_mm

    def ray_hit(self, origin_B: ArrayLike, direction_B: ArrayLike) -> tuple[float | None, NDArray[np.float64] | None]:
        """Distance along the ray to the wall and the hit point in B; (None, None) if no wall is hit.

        The ray misses if it is parallel to the wall, points away from it, or passes through the
        opening.
        """
        o = np.asarray(origin_B, dtype=float)
        d = np.asarray(direction_B, dtype=float)
        denom = float(self.normal_B @ d)
        if denom <= 1e-12:
            return None, None
        t = (self.offset_B - float(self.normal_B @ o)) / denom
        if t <= 0:
            return None, None
        hit = o + t * d
        hit_T = apply_pose(invert_pose(self.T_B_T), hit)
        if self.in_opening(hit_T[:2])[0]:
            return None, None
        return t, hit


def sample_world(config: WorldConfig, rng: np.random.Generator) -> World:
    """The car body at a random posture: a uniform draw within the configured half-ranges.

    The posture is a rotation about ``config.posture_pivot`` (the corner, i.e. T's origin, or the
    opening's centre; fixed-angle ranges about T's axes) and a translation along T's axes, both
    applied to the nominal placement.
    """
    T_nom = config.T_B_T_nominal()
    dt = rng.uniform(-1.0, 1.0, 3) * np.asarray(config.posture_translation_mm)
    angles = np.deg2rad(rng.uniform(-1.0, 1.0, 3) * np.asarray(config.posture_rotation_deg))
    R = xyz_fixed_to_matrix(angles[2], angles[1], angles[0])
    if config.posture_pivot == "corner":
        centre_T = np.zeros(3)
    else:
        centre_T = np.array([-config.width_mm / 2.0, config.height_mm / 2.0, 0.0])
    # Rotate about the pivot, expressed in T, then translate (translation in T's axes).
    T_T_Tnew = make_pose(np.eye(3), centre_T) @ make_pose(R, np.zeros(3)) @ make_pose(np.eye(3), -centre_T)
    T_T_Tnew[:3, 3] += dt
    T_B_T = T_nom @ T_T_Tnew
    return World(
        T_B_T, config.width_mm, config.height_mm, config.corner_radius_mm, placement_seed(T_B_T)
    )


def nominal_world(config: WorldConfig) -> World:
    """The car body exactly at its nominal placement (its surface seeded from that placement too)."""
    T_B_T = config.T_B_T_nominal()
    return World(
        T_B_T, config.width_mm, config.height_mm, config.corner_radius_mm, placement_seed(T_B_T)
    )


def placement_seed(T_B_T: ArrayLike) -> int:
    """A surface seed derived from a placement (CRC-32 of its float64 bytes); draws nothing from an rng."""
    return zlib.crc32(np.ascontiguousarray(T_B_T, dtype=np.float64).tobytes())
