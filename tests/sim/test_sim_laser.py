"""The LK-G500 model: ray-plane distances, the opening, range limits, linearity and noise."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config.sim import LaserSimConfig, SimConfig, WorldConfig
from cellctl.geometry.pose import Pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix
from cellctl.ports import LaserStatus
from cellctl.sim.laser import LaserModel
from cellctl.sim.world import World, sample_world

QUIET = LaserSimConfig(linearity_fraction_fs=0.0, noise_mm=0.0)


def _world(seed: int = 3) -> World:
    return sample_world(WorldConfig(), np.random.default_rng(seed))


def _aim(
    world: World, laser: LaserSimConfig, spot_T: tuple[float, float], standoff_mm: float, tilt: np.ndarray | None = None
) -> Pose:
    """A true flange pose whose beam meets the wall at spot_T (x, y in T) after standoff_mm."""
    R_H_C = SimConfig().camera.hand_eye.T_H_C()[:3, :3]
    R = world.T_B_T[:3, :3] @ R_H_C.T  # camera facing the wall, the laser nearly along its normal
    if tilt is not None:
        R = axis_angle_to_matrix(tilt) @ R
    spot_B = world.T_B_T[:3, :3] @ np.array([spot_T[0], spot_T[1], 0.0]) + world.T_B_T[:3, 3]
    return make_pose(R, spot_B - R @ (laser.r + standoff_mm * laser.l))


def test_distance_equals_the_analytic_ray_plane_intersection() -> None:
    world = _world()
    laser = LaserModel(QUIET, seed=1)
    rng = np.random.default_rng(0)
    n, D = world.normal_B, world.offset_B
    checked = 0
    for _ in range(300):
        spot = (rng.uniform(30.0, 300.0), rng.uniform(-300.0, 1800.0))  # right of the opening: always wall
        T = _aim(world, QUIET, spot, rng.uniform(260.0, 440.0), tilt=np.radians(rng.uniform(-8.0, 8.0, 3)))
        origin = T[:3, :3] @ QUIET.r + T[:3, 3]
        direction = T[:3, :3] @ QUIET.l
        expected = (D - n @ origin) / (n @ direction)  # n . (o + t l) = D
        status, d = laser.reading(T, world)
        if not 250.0 <= expected <= 450.0:
            continue
        assert status is LaserStatus.OK
        assert d == pytest.approx(expected, abs=1e-9)
        checked += 1
    assert checked > 200


def test_spots_in_the_opening_give_no_return() -> None:
    world = _world()
    laser = LaserModel(QUIET, seed=1)
    for spot in [(-1000.0, 750.0), (-5.0, 400.0), (-1500.0, 3.0), (-20.0, 20.0)]:  # the last one inside the arc
        assert laser.reading(_aim(world, QUIET, spot, 350.0), world) == (LaserStatus.OVER_RANGE_FAR, None)
    # Just outside the rounded corner there is wall.
    status, d = laser.reading(_aim(world, QUIET, (-5.0, 5.0), 350.0), world)
    assert status is LaserStatus.OK and d == pytest.approx(350.0, abs=1e-9)
    # The status for a missing return is configurable (the LK-G manual pages at hand leave it open).
    for name, status in [("over_range_near", LaserStatus.OVER_RANGE_NEAR), ("no_value", LaserStatus.NO_VALUE)]:
        cfg = QUIET.model_copy(update={"no_return_status": name})
        assert LaserModel(cfg, seed=1).reading(_aim(world, QUIET, (-1000.0, 750.0), 350.0), world) == (status, None)


def test_beam_facing_away_from_the_wall_gives_no_return() -> None:
    world = _world()
    laser = LaserModel(QUIET, seed=1)
    T = _aim(world, QUIET, (100.0, 100.0), 350.0)
    origin = T[:3, :3] @ QUIET.r + T[:3, 3]
    flipped = make_pose(axis_angle_to_matrix(np.array([0.0, 0.0, np.pi])), np.zeros(3))  # turn 180 deg about B z
    T_away = make_pose(flipped[:3, :3] @ T[:3, :3], origin - flipped[:3, :3] @ T[:3, :3] @ QUIET.r)
    assert laser.reading(T_away, world) == (LaserStatus.OVER_RANGE_FAR, None)


@pytest.mark.parametrize(
    ("standoff", "status"),
    [
        (200.0, LaserStatus.OVER_RANGE_NEAR),
        (249.99, LaserStatus.OVER_RANGE_NEAR),
        (250.01, LaserStatus.OK),
        (449.99, LaserStatus.OK),
        (450.01, LaserStatus.OVER_RANGE_FAR),
        (900.0, LaserStatus.OVER_RANGE_FAR),
    ],
)
def test_out_of_range_status(standoff: float, status: LaserStatus) -> None:
    world = _world()
    got, d = LaserModel(QUIET, seed=1).reading(_aim(world, QUIET, (100.0, 500.0), standoff), world)
    assert got is status
    assert (d is None) == (status is not LaserStatus.OK)


def test_linearity_is_a_fixed_smooth_curve_within_its_bound() -> None:
    cfg = LaserSimConfig(noise_mm=0.0)
    laser = LaserModel(cfg, seed=4)
    bound = 0.0002 * 200.0
    d = np.linspace(250.0, 450.0, 20001)
    e = laser.linearity_error(d)
    assert np.max(np.abs(e)) <= bound * (1 + 1e-6)
    assert np.max(np.abs(e)) >= 0.999 * bound  # it uses its whole band
    # Smooth: no step between neighbours larger than its slope allows (white noise would jump).
    assert np.max(np.abs(np.diff(e))) < 5 * bound * 2 * np.pi / 200.0 * (d[1] - d[0])
    # Linearity, not gain: no straight-line part left.
    slope, offset = np.polyfit(d, e, 1)
    assert abs(slope * 200.0) < 1e-3 * bound and abs(slope * 350.0 + offset) < 1e-3 * bound
    # Fixed for a sensor (seed), different for another.
    np.testing.assert_array_equal(e, LaserModel(cfg, seed=4).linearity_error(d))
    assert not np.allclose(e, LaserModel(cfg, seed=5).linearity_error(d))
    # And it is what the reading carries on top of the true distance.
    world = _world()
    for standoff in (260.0, 333.3, 440.0):
        status, got = laser.reading(_aim(world, cfg, (100.0, 500.0), standoff), world)
        assert status is LaserStatus.OK
        assert got == pytest.approx(standoff + float(laser.linearity_error(standoff)), abs=1e-9)


def test_noise_statistics_match_the_configuration() -> None:
    cfg = LaserSimConfig(linearity_fraction_fs=0.0, noise_mm=0.002)
    laser = LaserModel(cfg, seed=9)
    world = _world()
    T = _aim(world, cfg, (100.0, 500.0), 350.0)
    d = np.array([laser.reading(T, world)[1] for _ in range(4000)])
    assert np.mean(d) == pytest.approx(350.0, abs=4 * 0.002 / np.sqrt(4000))
    assert np.std(d, ddof=1) == pytest.approx(0.002, rel=0.06)
