"""Scoring an install: the paper's six figures against the truth."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config.sim import GlassConfig, LaserSimConfig, RobotSimConfig, SimConfig
from cellctl.geometry.pose import invert_pose, make_pose
from cellctl.geometry.rotation import xyz_fixed_to_matrix
from cellctl.sim.cell import SimCell
from cellctl.sim.truth import score_install

NO_REPEAT = RobotSimConfig(repeatability_mm=0.0, repeatability_orientation_deg=0.0)


def test_true_install_pose_scores_zero() -> None:
    for glass in (GlassConfig(), GlassConfig(rotation_xyz_fixed_deg=(0.4, -0.3, 1.2))):
        cell = SimCell(SimConfig(seed=2, glass=glass))
        truth = cell.truth()
        err = truth.score(truth.install_flange_pose())
        assert np.max(np.abs(err.position_mm)) < 1e-9 and np.max(np.abs(err.rotation_deg)) < 1e-9
        assert err.within(0.5, 1.0)


@pytest.mark.parametrize(
    ("t_mm", "angles_deg"),
    [
        ((0.4, -0.3, 0.25), (0.6, -0.8, 0.3)),
        ((-1.5, 2.0, -0.7), (0.0, 0.0, -2.5)),
        ((0.0, 0.0, 0.0), (-1.1, 0.9, 0.0)),
    ],
)
def test_known_perturbation_gives_the_six_figures(t_mm: tuple[float, ...], angles_deg: tuple[float, ...]) -> None:
    cell = SimCell(SimConfig(seed=3, glass=GlassConfig(rotation_xyz_fixed_deg=(0.2, 0.1, -0.5))))
    truth = cell.truth()
    rx, ry, rz = np.radians(angles_deg)
    # The glass corner G placed at a known pose in T: G = T @ D, so the flange is T @ D @ inv(T_H_G).
    D = make_pose(xyz_fixed_to_matrix(rz, ry, rx), t_mm)
    T_B_H = truth.T_B_T @ D @ invert_pose(truth.T_H_G)
    err = score_install(T_B_H, truth.T_B_T, truth.T_H_G)
    np.testing.assert_allclose(err.position_mm, t_mm, atol=1e-9)
    np.testing.assert_allclose(err.rotation_deg, angles_deg, atol=1e-9)
    assert err.as_dict()["drx_deg"] == pytest.approx(angles_deg[0], abs=1e-9)
    assert err.within(0.5, 1.0) == (max(map(abs, t_mm)) <= 0.5 and max(map(abs, angles_deg)) <= 1.0)


def test_executed_install_is_scored_at_the_true_pose() -> None:
    cell = SimCell(SimConfig(seed=4, robot=NO_REPEAT))
    # A perfect controller commands the belief that the robot's accuracy error maps onto T.
    cell.execute(cell.install_command())
    err = cell.install_error()
    assert np.max(np.abs(err.position_mm)) < 1e-9 and np.max(np.abs(err.rotation_deg)) < 1e-9
    # Commanding the true install pose itself as a belief leaves the accuracy error, bounded by its maximum.
    cell.execute(cell.truth().install_flange_pose())
    err = cell.install_error()
    assert 1e-3 < np.linalg.norm(err.position_mm) <= NO_REPEAT.absolute_accuracy_mm
    # The robot's read-back is the belief, not the truth.
    np.testing.assert_array_equal(cell.belief_flange_pose(), cell.truth().install_flange_pose())


def test_truth_exposes_the_mountings() -> None:
    cfg = SimConfig(laser=LaserSimConfig())
    truth = SimCell(cfg).truth()
    np.testing.assert_array_equal(truth.T_H_C, cfg.camera.hand_eye.T_H_C())
    np.testing.assert_array_equal(truth.laser_r, cfg.laser.r)
    np.testing.assert_allclose(np.linalg.norm(truth.laser_l), 1.0, atol=1e-12)
    np.testing.assert_array_equal(truth.T_H_G, cfg.glass.T_H_G())
    T_B_H = truth.install_flange_pose()
    np.testing.assert_allclose(truth.camera_pose(T_B_H), T_B_H @ truth.T_H_C)
