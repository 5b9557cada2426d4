"""The gripper's release in the twin: SimRobot, the ABB fake wired to the twin, and the robot wrappers."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from cellctl.cell.robots import ReducedSpeedRobot, TrackedRobot
from cellctl.config.devices import SimAbbDevice
from cellctl.config.sim import SimConfig
from cellctl.ports import (
    CartesianPose,
    DeviceDisconnected,
    DeviceRejected,
    DeviceTimeout,
    MotionInterrupted,
    MotionRequest,
    Robot,
)
from cellctl.service.sim_fakes import abb_on_fake
from cellctl.sim.cell import SimCell
from cellctl.sim.devices import SimRobot

pytestmark = pytest.mark.timeout(60)

T_OUT = 5.0


def _shifted(cell: SimCell, dx: float = 0.0, dy: float = 0.0, dz: float = 0.0) -> MotionRequest:
    T = cell.belief_flange_pose()
    T[:3, 3] += [dx, dy, dz]
    return MotionRequest(CartesianPose.from_matrix(T), speed_mm_s=1000.0)


async def _release_then_back_off(cell: SimCell, robot: Robot) -> None:
    """Move, release, back off: the glass stays where the flange truly stood at the release."""
    await robot.move(_shifted(cell, dy=80.0, dz=-40.0), timeout_s=T_OUT)
    assert cell.glass_on_gripper and cell.installed_glass() is None
    true_at_release = cell.true_flange_pose()
    # The twin's robot is not exact: the truth is not the reported pose, and the glass follows the truth.
    assert np.linalg.norm(true_at_release[:3, 3] - (await robot.read_pose(timeout_s=T_OUT)).to_matrix()[:3, 3]) > 1e-6
    await robot.set_gripper(False, timeout_s=T_OUT)
    installed = cell.installed_glass()
    assert installed is not None and not cell.glass_on_gripper
    np.testing.assert_allclose(installed, true_at_release @ cell.T_H_G, atol=1e-9)
    await robot.move(_shifted(cell, dz=150.0), timeout_s=T_OUT)  # back off
    assert np.linalg.norm(cell.true_flange_pose()[:3, 3] - true_at_release[:3, 3]) > 100.0
    np.testing.assert_allclose(cell.installed_glass(), true_at_release @ cell.T_H_G, atol=1e-9)
    # Vacuum on again picks nothing up; the glass stays installed.
    await robot.set_gripper(True, timeout_s=T_OUT)
    np.testing.assert_allclose(cell.installed_glass(), true_at_release @ cell.T_H_G, atol=1e-9)
    assert not cell.glass_on_gripper


async def test_sim_robot_release_leaves_the_glass_where_the_flange_truly_stood() -> None:
    cell = SimCell(SimConfig(time_scale=0.0))
    robot = SimRobot(cell)
    assert isinstance(robot, Robot)
    await _release_then_back_off(cell, robot)


async def test_sim_robot_release_is_refused_while_moving() -> None:
    cell = SimCell(SimConfig(time_scale=1.0))  # real time: a 1 m move takes about 1.6 s
    robot = SimRobot(cell)
    with pytest.raises(DeviceTimeout, match="still moving"):
        await robot.move(_shifted(cell, dy=1000.0), timeout_s=0.1)
    with pytest.raises(DeviceRejected, match="gripper release refused: the robot is moving"):
        await robot.set_gripper(False, timeout_s=T_OUT)
    assert cell.glass_on_gripper and cell.installed_glass() is None
    await robot.stop(timeout_s=T_OUT)
    await robot.set_gripper(False, timeout_s=T_OUT)  # at a standstill
    assert not cell.glass_on_gripper


async def test_sim_robot_gripper_timeouts_and_arguments() -> None:
    cell = SimCell(SimConfig.model_validate({"time_scale": 1.0, "robot": {"call_latency_s": 0.2}}))
    robot = SimRobot(cell)
    with pytest.raises(DeviceTimeout, match="no answer within 0.05 s"):
        await robot.set_gripper(False, timeout_s=0.05)
    assert cell.glass_on_gripper  # not switched
    with pytest.raises(ValueError, match="timeout_s"):
        await robot.set_gripper(False, timeout_s=0.0)
    with pytest.raises(TypeError, match="True or False"):
        await robot.set_gripper(0, timeout_s=T_OUT)  # type: ignore[arg-type]
    await robot.close()
    with pytest.raises(DeviceDisconnected):
        await robot.set_gripper(False, timeout_s=T_OUT)
    assert cell.glass_on_gripper


async def test_the_real_driver_on_the_fake_releases_the_twins_glass() -> None:
    cell = SimCell(SimConfig(time_scale=0.001))
    driver, close, _jog = abb_on_fake(cell, SimAbbDevice(kind="sim_abb"))
    try:
        await driver.connect(timeout_s=T_OUT)
        await _release_then_back_off(cell, driver)
    finally:
        await close()


async def test_the_real_driver_release_while_moving_keeps_the_glass() -> None:
    cell = SimCell(SimConfig(time_scale=1.0))
    driver, close, _jog = abb_on_fake(cell, SimAbbDevice(kind="sim_abb"))
    try:
        await driver.connect(timeout_s=T_OUT)
        move = asyncio.create_task(driver.move(_shifted(cell, dy=300.0), timeout_s=10.0))
        await asyncio.sleep(0.2)
        with pytest.raises(DeviceRejected, match=r"gripper release refused: the robot is moving.*110 BUSY"):
            await driver.set_gripper(False, timeout_s=T_OUT)
        assert cell.glass_on_gripper and cell.installed_glass() is None
        await driver.stop(timeout_s=T_OUT)
        with pytest.raises(MotionInterrupted):
            await asyncio.wait_for(move, T_OUT)
    finally:
        await close()


async def test_wrappers_pass_the_gripper_through_but_commissioning_refuses_it() -> None:
    cell = SimCell(SimConfig(time_scale=0.0))
    tracked = TrackedRobot(SimRobot(cell))
    assert isinstance(tracked, Robot)
    reduced = ReducedSpeedRobot(SimRobot(cell), 250.0, 30.0)
    with pytest.raises(DeviceRejected, match="not switched during commissioning"):
        await reduced.set_gripper(False, timeout_s=T_OUT)
    assert cell.glass_on_gripper
    await tracked.set_gripper(False, timeout_s=T_OUT)
    assert not cell.glass_on_gripper and cell.installed_glass() is not None
