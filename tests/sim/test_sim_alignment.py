"""The laser alignment (paper section 3) run against the twin's robot and laser models."""

from __future__ import annotations

import numpy as np

from cellctl.config.schema import CellConfig
from cellctl.config.sim import SimConfig
from cellctl.geometry.pose import make_pose
from cellctl.ports import LaserStatus
from cellctl.sim.alignment_run import run_alignment, simulate_alignment
from cellctl.sim.cell import SimCell
from cellctl.sim.streams import LASER_NOISE, rng_stream


def _config(**sim: dict) -> CellConfig:
    return CellConfig.model_validate({"sim": sim})


def test_alignment_is_exact_with_every_error_source_off() -> None:
    cfg = _config(
        robot={
            "repeatability_mm": 0.0,
            "repeatability_orientation_deg": 0.0,
            "absolute_accuracy_mm": 0.0,
            "absolute_accuracy_deg": 0.0,
        },
        laser={"noise_mm": 0.0, "linearity_fraction_fs": 0.0},
    )
    cell = SimCell(cfg.sim, seed=3)
    for _ in range(3):
        run = run_alignment(cell, cfg)
        assert run.camera_axis_error_rad < 1e-9
        assert abs(run.distance_error_mm) < 1e-6
        cell.new_car_body()


def test_alignment_with_the_paper_errors_is_deterministic_and_within_tolerance() -> None:
    cfg = _config()
    runs = [simulate_alignment(cfg, np.random.default_rng(21)) for _ in range(2)]
    assert runs[0].camera_axis_error_rad == runs[1].camera_axis_error_rad
    assert runs[0].distance_error_mm == runs[1].distance_error_mm
    cell = SimCell(cfg.sim, seed=5)
    for _ in range(5):
        run = run_alignment(cell, cfg)
        assert np.degrees(run.camera_axis_error_rad) < 0.05
        assert abs(run.distance_error_mm) < 0.5
        cell.new_car_body()


def test_switching_a_source_off_leaves_the_other_draws_alone() -> None:
    """The laser's noise values are the same whether or not the robot's repeatability is on."""
    base = SimConfig.model_validate({"laser": {"linearity_fraction_fs": 0.0}})
    quiet_robot = SimConfig.model_validate(
        {
            "laser": {"linearity_fraction_fs": 0.0},
            "robot": {"repeatability_mm": 0.0, "repeatability_orientation_deg": 0.0},
        }
    )
    expected = rng_stream(8, LASER_NOISE).normal(size=6) * base.laser.noise_mm
    true_poses = []
    for sim in (base, quiet_robot):
        cell = SimCell(sim, seed=8)
        world = cell.world()
        R = world.T_B_T[:3, :3] @ cell.T_H_C[:3, :3].T
        spot = world.T_B_T[:3, :3] @ np.array([100.0, 600.0, 0.0]) + world.T_B_T[:3, 3]
        X = make_pose(R, spot - R @ (sim.laser.r + 350.0 * sim.laser.l))
        noise, poses = [], []
        for _ in range(6):
            T = cell.execute(X)  # each move draws the robot's noise between the readings
            d_true = cell.laser_model.true_distance(T, world)
            status, d = cell.laser_reading()
            assert status is LaserStatus.OK and d is not None and d_true is not None
            noise.append(d - d_true)
            poses.append(T)
        np.testing.assert_allclose(noise, expected, rtol=0, atol=1e-10)
        true_poses.append(poses)
    assert not np.allclose(true_poses[0], true_poses[1])  # the robot's noise was on in one of them
