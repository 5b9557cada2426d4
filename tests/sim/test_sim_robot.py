"""The IRB 7600 model: belief versus truth, accuracy field, repeatability, reach and motion time."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config.sim import RobotSimConfig
from cellctl.geometry.pose import Pose, invert_pose, make_pose, pose_error
from cellctl.geometry.rotation import axis_angle_to_matrix, matrix_to_axis_angle, xyz_fixed_to_matrix
from cellctl.geometry.motion import TrapezoidProfile, interpolate_pose
from cellctl.sim.arm import RobotArm, RobotBusy
from cellctl.sim.robot import ISO_9283_RP_PER_SIGMA, ReachError, RobotModel
from cellctl.sim.timeline import TwinTimeline

R_DOWN = xyz_fixed_to_matrix(0.0, 0.0, np.pi)  # flange z down, x towards the wall (+x of the base)


def _pose(x: float, y: float, z: float, R: np.ndarray = R_DOWN) -> Pose:
    return make_pose(R, [x, y, z])


def _random_poses(rng: np.random.Generator, n: int) -> list[Pose]:
    """Poses whose wrist centre fills the reachable shell (0.5 .. 3.1 m from the reach centre)."""
    out = []
    while len(out) < n:
        R = axis_angle_to_matrix(rng.normal(size=3))
        w = rng.uniform(-3100.0, 3100.0, 3)
        if 600.0 < np.linalg.norm(w) < 3000.0:
            out.append(make_pose(R, w + np.array([0.0, 0.0, 780.0]) + 250.0 * R[:, 2]))
    return out


def test_iso_9283_sigma_interpretation() -> None:
    # mean and std of a chi(3) variable: 2 sqrt(2/pi) and sqrt(3 - 8/pi).
    assert ISO_9283_RP_PER_SIGMA == pytest.approx(3.6160, abs=1e-4)
    assert RobotModel(RobotSimConfig(), seed=1).sigma_position_mm == pytest.approx(0.1 / 3.616, rel=1e-3)


def test_reach_check_refuses_targets_outside_the_envelope() -> None:
    model = RobotModel(RobotSimConfig(), seed=1)
    model.check_reach(_pose(1500.0, 0.0, 1500.0))
    with pytest.raises(ReachError, match="out of reach") as info:
        model.check_reach(_pose(3200.0, 0.0, 1500.0))
    assert info.value.distance_mm > 3100.0
    with pytest.raises(ReachError, match="too close"):
        model.check_reach(_pose(100.0, 0.0, 780.0))
    with pytest.raises(ReachError):
        model.execute(_pose(0.0, 3500.0, 780.0))
    # A linear path through the arm's inner dead zone is refused even with both ends reachable.
    with pytest.raises(ReachError, match="linear path"):
        model.check_path(_pose(900.0, 0.0, 530.0), _pose(-900.0, 0.0, 530.0))


def test_accuracy_field_is_bounded_smooth_and_pose_dependent() -> None:
    cfg = RobotSimConfig()
    model = RobotModel(cfg, seed=2)
    poses = _random_poses(np.random.default_rng(0), 6000)
    dp, dth = zip(*(model.accuracy_error(T) for T in poses))
    pos = np.linalg.norm(dp, axis=1)
    rot = np.degrees(np.linalg.norm(dth, axis=1))
    assert pos.max() <= cfg.absolute_accuracy_mm + 1e-12
    assert rot.max() <= cfg.absolute_accuracy_deg + 1e-12
    assert pos.max() > 0.5 * cfg.absolute_accuracy_mm and rot.max() > 0.5 * cfg.absolute_accuracy_deg
    # Smooth: a 10 mm move changes the error by at most the field's slope times 10 mm, which is small.
    rng = np.random.default_rng(1)
    for T in poses[:500]:
        step = rng.normal(size=3)
        T2 = T.copy()
        T2[:3, 3] += 10.0 * step / np.linalg.norm(step)
        change = np.linalg.norm(model.accuracy_error(T2)[0] - model.accuracy_error(T)[0])
        assert change <= model._position_field.lipschitz * 10.0 + 1e-12
        assert change < 0.02
    # Pose-dependent: the same position with another orientation has another error.
    T = poses[0]
    T_turned = make_pose(T[:3, :3] @ xyz_fixed_to_matrix(0.0, np.pi / 2, 0.0), T[:3, 3])
    assert np.linalg.norm(model.accuracy_error(T)[0] - model.accuracy_error(T_turned)[0]) > 1e-3


def test_belief_and_truth_and_relative_moves() -> None:
    cfg = RobotSimConfig(repeatability_mm=0.0, repeatability_orientation_deg=0.0)
    model = RobotModel(cfg, seed=3)
    X = _pose(1300.0, -200.0, 1400.0)
    true = model.execute(X)
    dt, dr = pose_error(X, true)
    assert 1e-3 < np.linalg.norm(dt) <= 0.5  # the controller's belief is off by the accuracy error
    # command_for inverts E: commanding it lands the flange exactly on the wanted true pose.
    np.testing.assert_allclose(model.execute(model.command_for(X)), X, atol=1e-9)
    # A relative move of 20 mm, taught versus moved: the accuracy error mostly cancels.
    X2 = X.copy()
    X2[:3, 3] += [0.0, 20.0, 0.0]
    rel_true = invert_pose(true) @ model.execute(X2)
    rel_belief = invert_pose(X) @ X2
    rel_error = np.linalg.norm(rel_true[:3, 3] - rel_belief[:3, 3])
    assert rel_error < 0.02 and rel_error < 0.2 * np.linalg.norm(dt)


def test_repeatability_statistics_match_the_configuration() -> None:
    cfg = RobotSimConfig(absolute_accuracy_mm=0.0, absolute_accuracy_deg=0.0)
    model = RobotModel(cfg, seed=4)
    X = _pose(1300.0, 0.0, 1400.0)
    poses = np.array([model.execute(X) for _ in range(4000)])
    p = poses[:, :3, 3]
    l = np.linalg.norm(p - p.mean(axis=0), axis=1)  # noqa: E741 - ISO 9283's name
    rp = l.mean() + 3.0 * l.std(ddof=1)  # ISO 9283 pose repeatability
    assert rp == pytest.approx(cfg.repeatability_mm, rel=0.05)
    np.testing.assert_allclose(p.mean(axis=0), X[:3, 3], atol=4 * model.sigma_position_mm / np.sqrt(4000) * 3)
    rotvecs = np.array([matrix_to_axis_angle(R @ X[:3, :3].T) for R in poses[:, :3, :3]])
    rp_angle = 3.0 * np.degrees(rotvecs.std(axis=0, ddof=1))  # ISO 9283: +-3 S per angle
    np.testing.assert_allclose(rp_angle, cfg.repeatability_orientation_deg, rtol=0.06)


def test_trapezoidal_motion_time() -> None:
    cfg = RobotSimConfig()
    model = RobotModel(cfg, seed=1)
    A = _pose(1000.0, -1000.0, 1400.0)
    # Long move: accelerate 0.5 s, cruise, decelerate 0.5 s: D/v + v/a.
    assert model.motion_time(A, _pose(1000.0, 1000.0, 1400.0)) == pytest.approx(2000 / 1000 + 1000 / 2000 + 0.15)
    # Short move: a triangle, 2 sqrt(D/a).
    assert model.motion_time(A, _pose(1000.0, -900.0, 1400.0)) == pytest.approx(2 * np.sqrt(100 / 2000) + 0.15)
    # A slower requested speed is honoured; a faster one is capped at the robot's limit.
    assert model.motion_time(A, _pose(1000.0, 1000.0, 1400.0), speed_mm_s=500.0) == pytest.approx(4 + 0.25 + 0.15)
    assert model.motion_time(A, _pose(1000.0, 1000.0, 1400.0), speed_mm_s=5000.0) == pytest.approx(2.65)
    # A pure 90 deg turn is timed by the rotation limits (60 deg/s, 120 deg/s^2).
    turned = make_pose(A[:3, :3] @ xyz_fixed_to_matrix(np.pi / 2, 0.0, 0.0), A[:3, 3])
    assert model.motion_time(A, turned) == pytest.approx(90 / 60 + 60 / 120 + 0.15)
    profile = TrapezoidProfile(2000.0, 1000.0, 2000.0)
    s = [profile.travelled(t) for t in np.linspace(0.0, profile.duration, 501)]
    assert s[0] == 0.0 and s[-1] == 2000.0 and np.all(np.diff(s) >= 0)
    np.testing.assert_allclose(interpolate_pose(A, turned, 0.5)[:3, 3], A[:3, 3])


def test_arm_reports_belief_and_refuses_a_second_motion() -> None:
    now = [100.0]
    model = RobotModel(RobotSimConfig(), seed=5)
    arm = RobotArm(model, time_scale=1.0, clock=lambda: now[0])
    start = arm.belief_pose()
    np.testing.assert_array_equal(start, RobotSimConfig().T_B_H_home())
    X = _pose(1300.0, 300.0, 1500.0)
    motion = arm.start(X, 500.0)
    with pytest.raises(RobotBusy):
        arm.start(_pose(1300.0, 0.0, 1500.0))
    now[0] += 0.5 * (motion.t_end - motion.t_start)
    mid = arm.belief_pose()
    assert 0.0 < np.linalg.norm(mid[:3, 3] - start[:3, 3]) < np.linalg.norm(X[:3, 3] - start[:3, 3])
    now[0] = motion.t_end
    np.testing.assert_array_equal(arm.belief_pose(), X)
    assert not arm.moving()
    np.testing.assert_array_equal(arm.true_pose(), motion.target_true)
    assert np.linalg.norm(arm.true_pose()[:3, 3] - X[:3, 3]) > 1e-4


def test_determinism_and_independent_streams() -> None:
    X = _pose(1300.0, 0.0, 1400.0)
    a, b = RobotModel(RobotSimConfig(), seed=7), RobotModel(RobotSimConfig(), seed=7)
    seq_a = [a.execute(X) for _ in range(5)]
    np.testing.assert_array_equal(seq_a, [b.execute(X) for _ in range(5)])
    assert not np.allclose(seq_a[0], RobotModel(RobotSimConfig(), seed=8).execute(X))
    # Switching the accuracy error off leaves the repeatability draws exactly as they were.
    no_acc = RobotModel(RobotSimConfig(absolute_accuracy_mm=0.0, absolute_accuracy_deg=0.0), seed=7)
    ref = RobotModel(RobotSimConfig(), seed=7)
    np.testing.assert_array_equal([ref.draw_noise() for _ in range(5)], [no_acc.draw_noise() for _ in range(5)])
    # ...and switching repeatability off leaves the accuracy field unchanged.
    no_rep = RobotModel(RobotSimConfig(repeatability_mm=0.0, repeatability_orientation_deg=0.0), seed=7)
    np.testing.assert_array_equal(no_rep.deform(X), ref.deform(X))


def test_the_time_line_says_what_each_move_was_spent_on_and_a_stop_takes_back_the_rest() -> None:
    now = [0.0]
    cell_line = TwinTimeline(1.0, clock=lambda: now[0])
    arm = RobotArm(RobotModel(RobotSimConfig(), seed=5), time_scale=1.0, clock=lambda: now[0],
                   waited=cell_line.waited, line=cell_line.now)  # fmt: skip
    A = arm.belief_pose()
    along = make_pose(A[:3, :3], A[:3, 3] + [0.0, 400.0, 0.0])
    first = arm.start(along, 800.0, 30.0).duration_s
    now[0] += first
    turned = make_pose(along[:3, :3] @ xyz_fixed_to_matrix(0.0, 0.0, np.radians(90.0)), along[:3, 3])
    second = arm.start(turned, 800.0, 45.0).duration_s
    # 400 mm at 800 mm/s: 0.5 s plus the ramps; 90 deg at 45 deg/s: 2 s plus the ramps
    assert first == pytest.approx(0.5 + 800.0 / RobotSimConfig().acceleration_mm_s2 + RobotSimConfig().settle_time_s)
    assert second > 2.0
    now[0] += 0.5  # a stop half a second into the turn takes the rest back
    arm.stop()
    spent = cell_line.spent()
    assert set(spent) == {"moves at 800 mm/s", "turns at 45 deg/s"}
    assert spent["moves at 800 mm/s"] == pytest.approx(first) and spent["turns at 45 deg/s"] == pytest.approx(0.5)
