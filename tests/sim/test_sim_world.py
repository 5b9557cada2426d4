"""The car body: its opening, its random posture, and the cell's reproducibility for a seed."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config.sim import SimConfig, WorldConfig
from cellctl.geometry.pose import invert_pose
from cellctl.geometry.rotation import matrix_to_xyz_fixed
from cellctl.sim.cell import SimCell
from cellctl.sim.streams import WORLD_POSTURE, rng_stream
from cellctl.sim.world import nominal_world, sample_world


def test_rounded_corner_of_the_opening() -> None:
    world = nominal_world(WorldConfig(corner_radius_mm=30.0))
    # Arc centre at (-30, 30): inside the arc is opening, the corner's cusp outside it is wall.
    assert world.in_opening([-20.0, 20.0])[0]
    assert not world.in_opening([-5.0, 5.0])[0]
    assert world.in_opening([-1000.0, 750.0])[0]  # centre of the opening
    assert world.in_opening([-1000.0, 1.0])[0]  # just below the top edge
    assert not world.in_opening([-1000.0, -1.0])[0]  # just above it: wall
    assert not world.in_opening([1.0, 750.0])[0]  # right of the right edge
    assert not world.in_opening([-2001.0, 750.0])[0]
    assert not world.in_opening([-1000.0, 1501.0])[0]


@pytest.mark.parametrize("pivot", ["corner", "opening_centre"])
def test_posture_stays_within_the_configured_ranges(pivot: str) -> None:
    cfg = WorldConfig(posture_pivot=pivot)
    nominal = cfg.T_B_T_nominal()
    centre_T = np.zeros(3) if pivot == "corner" else np.array([-cfg.width_mm / 2, cfg.height_mm / 2, 0.0])
    rng = np.random.default_rng(5)
    shifts, angles = [], []
    for _ in range(400):
        world = sample_world(cfg, rng)
        rel = invert_pose(nominal) @ world.T_B_T
        shifts.append(rel[:3, :3] @ centre_T + rel[:3, 3] - centre_T)  # the pivot's displacement
        alpha, beta, gamma = matrix_to_xyz_fixed(rel[:3, :3])
        angles.append(np.degrees([gamma, beta, alpha]))
    shifts_a, angles_a = np.abs(shifts), np.abs(angles)
    assert np.all(shifts_a <= 20.0 + 1e-9) and np.all(angles_a <= 2.0 + 1e-9)
    # The draws use the ranges (uniform: the largest of 400 comes close to the limit).
    assert np.all(shifts_a.max(axis=0) > 18.0) and np.all(angles_a.max(axis=0) > 1.8)


def test_cell_is_reproducible_for_a_seed() -> None:
    a, b, c = SimCell(SimConfig(seed=11)), SimCell(SimConfig(seed=11)), SimCell(SimConfig(seed=12))
    np.testing.assert_array_equal(a.world().T_B_T, b.world().T_B_T)
    assert not np.allclose(a.world().T_B_T, c.world().T_B_T)
    for _ in range(3):
        np.testing.assert_array_equal(a.new_car_body().T_B_T, b.new_car_body().T_B_T)
    # The posture stream is the named one, so a caller can reproduce it alone.
    rng = rng_stream(11, WORLD_POSTURE)
    np.testing.assert_array_equal(sample_world(SimConfig().world, rng).T_B_T, SimCell(SimConfig(seed=11)).world().T_B_T)
