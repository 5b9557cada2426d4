"""The in-process simulated robot and laser behind the ports."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from cellctl.config.sim import SimConfig
from cellctl.geometry.pose import make_pose
from cellctl.ports import (
    CartesianPose,
    DeviceDisconnected,
    DeviceRejected,
    DeviceTimeout,
    DisplacementSensor,
    LaserStatus,
    MotionInterrupted,
    MotionRequest,
    Robot,
    UnreachableTarget,
)
from cellctl.sim.cell import SimCell
from cellctl.sim.devices import SimDisplacementSensor, SimRobot

pytestmark = pytest.mark.timeout(30)

T_OUT = 5.0


def _request(T: np.ndarray, speed_mm_s: float = 1000.0) -> MotionRequest:
    return MotionRequest(CartesianPose.from_matrix(T), speed_mm_s=speed_mm_s)


def _spot_pose(cell: SimCell, spot_T: tuple[float, float], standoff_mm: float) -> np.ndarray:
    """A belief target that aims the laser at spot_T on the true wall (noise-free robot: exact)."""
    world = cell.world()
    R = world.T_B_T[:3, :3] @ cell.T_H_C[:3, :3].T
    spot = world.T_B_T[:3, :3] @ np.array([spot_T[0], spot_T[1], 0.0]) + world.T_B_T[:3, 3]
    laser = cell.config.laser
    true = make_pose(R, spot - R @ (laser.r + standoff_mm * laser.l))
    return cell.robot_model.command_for(true)


def _quiet(time_scale: float = 0.0) -> SimConfig:
    return SimConfig.model_validate(
        {
            "seed": 6,
            "time_scale": time_scale,
            "robot": {"repeatability_mm": 0.0, "repeatability_orientation_deg": 0.0},
            "laser": {"noise_mm": 0.0, "linearity_fraction_fs": 0.0},
        }
    )


async def test_devices_implement_the_ports() -> None:
    cell = SimCell(SimConfig())
    assert isinstance(SimRobot(cell), Robot)
    assert isinstance(SimDisplacementSensor(cell), DisplacementSensor)


async def test_move_reports_the_belief_and_the_laser_sees_the_truth() -> None:
    cell = SimCell(_quiet())
    robot, laser = SimRobot(cell), SimDisplacementSensor(cell)
    X = _spot_pose(cell, (100.0, 600.0), 320.0)
    reply = await robot.move(_request(X), timeout_s=T_OUT)
    np.testing.assert_allclose(reply.to_matrix(), X, atol=1e-9)
    np.testing.assert_allclose((await robot.read_pose(timeout_s=T_OUT)).to_matrix(), X, atol=1e-9)
    assert np.linalg.norm(cell.true_flange_pose()[:3, 3] - X[:3, 3]) > 1e-4  # truth differs from belief
    reading = await laser.read(timeout_s=T_OUT)
    assert reading.status is LaserStatus.OK and reading.distance_mm == pytest.approx(320.0, abs=1e-6)
    assert not (await robot.state(timeout_s=T_OUT)).moving
    # Into the opening: no return, reported as over range.
    await robot.move(_request(_spot_pose(cell, (-600.0, 600.0), 320.0)), timeout_s=T_OUT)
    reading = await laser.read(timeout_s=T_OUT)
    assert reading.status is LaserStatus.OVER_RANGE_FAR and reading.distance_mm is None
    # After a reset the controller has no value until it samples again.
    laser.reset()
    assert (await laser.read(timeout_s=T_OUT)).status is LaserStatus.NO_VALUE
    assert (await laser.read(timeout_s=T_OUT)).status is LaserStatus.OVER_RANGE_FAR


async def test_unreachable_target_is_refused_and_nothing_moves() -> None:
    cell = SimCell(SimConfig(time_scale=0.0))
    robot = SimRobot(cell)
    before = cell.true_flange_pose()
    far = make_pose(np.diag([1.0, -1.0, -1.0]), [3400.0, 0.0, 1500.0])
    with pytest.raises(UnreachableTarget, match="out of reach"):
        await robot.move(_request(far), timeout_s=T_OUT)
    np.testing.assert_array_equal(cell.true_flange_pose(), before)


async def test_timeout_stop_and_busy() -> None:
    cell = SimCell(SimConfig(time_scale=1.0))  # real time: a 1 m move takes about 1.6 s
    robot = SimRobot(cell)
    start = cell.belief_flange_pose()
    target = start.copy()
    target[:3, 3] += [0.0, 1000.0, 0.0]
    with pytest.raises(DeviceTimeout, match="still moving"):
        await robot.move(_request(target), timeout_s=0.1)
    assert (await robot.state(timeout_s=T_OUT)).moving
    with pytest.raises(DeviceRejected, match="in progress"):
        await robot.move(_request(start), timeout_s=T_OUT)
    await robot.stop(timeout_s=T_OUT)
    assert not (await robot.state(timeout_s=T_OUT)).moving
    stopped = (await robot.read_pose(timeout_s=T_OUT)).to_matrix()
    travelled = stopped[1, 3] - start[1, 3]
    assert 0.0 < travelled < 1000.0
    # A move interrupted by a stop raises MotionInterrupted (on to the far target: about 1.6 s, so a stalled
    # test process cannot see it end before the stop; the way back was 12 mm, 0.3 s).
    again = asyncio.create_task(robot.move(_request(target), timeout_s=T_OUT))
    await asyncio.sleep(0.1)
    await robot.stop(timeout_s=T_OUT)
    with pytest.raises(MotionInterrupted):
        await again


async def test_call_timeouts_and_closing() -> None:
    cfg = SimConfig.model_validate({"time_scale": 1.0, "laser": {"read_latency_s": 0.2}})
    cell = SimCell(cfg)
    laser, robot = SimDisplacementSensor(cell), SimRobot(cell)
    with pytest.raises(DeviceTimeout):
        await laser.read(timeout_s=0.01)
    with pytest.raises(ValueError, match="timeout_s"):
        await laser.read(timeout_s=0.0)
    with pytest.raises(ValueError, match="timeout_s"):
        await robot.read_pose(timeout_s=float("nan"))
    assert await robot.ping(timeout_s=T_OUT) >= 0.0
    await laser.close()
    await laser.close()
    with pytest.raises(DeviceDisconnected):
        await laser.read(timeout_s=T_OUT)
    await robot.close()
    with pytest.raises(DeviceDisconnected):
        await robot.read_pose(timeout_s=T_OUT)
