"""The fake controller's default robot model and its frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

import _abb_quat as quat
from abb_robot.fake import DEFAULT_HOME, RobotModel, SimpleArmModel
from abb_robot.fake.robot import FakeRobot
from cellctl.ports import CartesianPose

Q_FORWARD = DEFAULT_HOME.quaternion_wxyz  # tool z along +x


def _pose(x: float, y: float, z: float, q: tuple[float, float, float, float] = Q_FORWARD) -> CartesianPose:
    return CartesianPose((x, y, z), q)


def test_default_model_is_a_robot_model() -> None:
    assert isinstance(SimpleArmModel(), RobotModel)


@pytest.mark.parametrize("seed", range(5))
def test_forward_kinematics_inverts_the_joint_solution(seed: int) -> None:
    model = SimpleArmModel(seed=seed)
    rng = np.random.default_rng(seed)
    checked = 0
    while checked < 40:
        p = rng.uniform([800, -1500, 300], [2600, 1500, 2200])
        q = quat.multiply(quat.from_rotation_vector(rng.normal(0, 0.5, 3)), Q_FORWARD)
        pose = _pose(*p, q=quat.normalise(q))
        if model.reachable(pose) is not None:
            continue
        back = model.pose_from_joints(model.joints(pose))
        assert np.allclose(back.position_mm, pose.position_mm, atol=1e-6)
        assert quat.angle_between(back.quaternion_wxyz, pose.quaternion_wxyz) < 1e-7  # acos resolution near 1
        checked += 1


def test_reach_sphere_and_dead_zone_refuse_with_reasons() -> None:
    model = SimpleArmModel()
    assert model.reachable(DEFAULT_HOME) is None
    far = model.reachable(_pose(3600.0, 0.0, 1500.0))
    assert far is not None and far.kind == "reach" and "reach sphere" in far.reason
    near = model.reachable(_pose(450.0, 0.0, 780.0 + 250.0, q=(1.0, 0.0, 0.0, 0.0)))
    assert near is not None and near.kind == "reach" and "dead zone" in near.reason


def test_axis_limits_refuse_a_wrist_bent_too_far() -> None:
    model = SimpleArmModel()
    # Tool z pointing back toward the robot: axis 5 would need about 180 degrees.
    back = quat.normalise(quat.multiply(quat.from_rotation_vector((0.0, math.pi, 0.0)), Q_FORWARD))
    refusal = model.reachable(_pose(2000.0, 0.0, 1500.0, q=back))
    assert refusal is not None and refusal.kind == "joint_limit" and "axis 5" in refusal.reason


def test_motion_time_follows_distance_and_speed() -> None:
    model = SimpleArmModel(acceleration_mm_s2=4000.0)
    a = DEFAULT_HOME
    b = _pose(2500.0, 0.0, 1500.0)
    assert model.motion_time(a, a, 100.0, 30.0, True) == 0.0
    t_slow = model.motion_time(a, b, 100.0, 30.0, True)
    t_fast = model.motion_time(a, b, 1000.0, 30.0, True)
    assert t_slow == pytest.approx(500.0 / 100.0 + 100.0 / 4000.0)
    assert t_fast == pytest.approx(500.0 / 1000.0 + 1000.0 / 4000.0)
    short = model.motion_time(a, _pose(2001.0, 0.0, 1500.0), 1000.0, 30.0, True)
    assert short == pytest.approx(2.0 * math.sqrt(1.0 / 4000.0))


def test_execute_adds_seeded_repeatability_noise() -> None:
    reached = [SimpleArmModel(repeatability_mm=0.05, seed=3).execute(DEFAULT_HOME) for _ in range(1)]
    again = SimpleArmModel(repeatability_mm=0.05, seed=3).execute(DEFAULT_HOME)
    assert reached[0] == again
    model = SimpleArmModel(repeatability_mm=0.05, repeatability_rad=0.0, seed=4)
    errors = np.array([np.subtract(model.execute(DEFAULT_HOME).position_mm, DEFAULT_HOME.position_mm)
                       for _ in range(2000)])
    assert np.std(errors, axis=0) == pytest.approx([0.05, 0.05, 0.05], rel=0.1)
    assert np.abs(errors.mean(axis=0)).max() < 0.01
    exact = SimpleArmModel(repeatability_mm=0.0, repeatability_rad=0.0).execute(DEFAULT_HOME)
    assert exact.position_mm == DEFAULT_HOME.position_mm


def test_bad_model_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match="repeatability_mm"):
        SimpleArmModel(repeatability_mm=-1.0)
    with pytest.raises(ValueError, match="limits_deg"):
        SimpleArmModel(limits_deg=((0.0, 1.0),))
    with pytest.raises(ValueError, match="home pose is not reachable"):
        FakeRobot(SimpleArmModel(), _pose(5000.0, 0.0, 0.0))


def test_tool_and_work_object_frames_round_trip() -> None:
    tool = CartesianPose((0.0, 0.0, 200.0), (1.0, 0.0, 0.0, 0.0))
    wobj = CartesianPose((100.0, -50.0, 20.0), quat.from_rotation_vector((0.0, 0.0, math.pi / 2)))
    robot = FakeRobot(SimpleArmModel(), DEFAULT_HOME, tools={"tLong": tool}, wobjs={"wTable": wobj})
    assert robot.tcp() == DEFAULT_HOME  # tool0 in wobj0
    robot.tool_name, robot.wobj_name = "tLong", "wTable"
    tcp = robot.tcp()
    # The TCP is 200 mm along the flange z (+x in base); the work object is turned 90 deg about z.
    base_tcp = np.array([2200.0, 0.0, 1500.0])
    expect = quat.to_matrix(wobj.quaternion_wxyz).T @ (base_tcp - np.array(wobj.position_mm))
    assert np.allclose(tcp.position_mm, expect, atol=1e-9)
    back = robot.tcp_to_flange(tcp)
    assert np.allclose(back.position_mm, DEFAULT_HOME.position_mm, atol=1e-9)
