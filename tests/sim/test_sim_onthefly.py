"""Readings on the move (issue 19): the twin's position feedback, laser storage and path deviation at speed."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest

from cellctl.config.sim import SimConfig
from cellctl.geometry.motion import interpolate_pose
from cellctl.geometry.pose import make_pose
from cellctl.ports import (
    CartesianPose,
    DeviceDisconnected,
    DeviceRejected,
    DeviceTimeout,
    MotionRequest,
    PoseSample,
    PoseStream,
    StoredReadings,
    StoringSensor,
)
from cellctl.sim.cell import SimCell
from cellctl.sim.devices import SimDisplacementSensor, SimRobot

pytestmark = pytest.mark.timeout(30)

T_OUT = 5.0
SPEED_MM_S = 500.0


def _config(time_scale: float = 0.001, **robot: float) -> SimConfig:
    """Seed 6 without the laser's noise (its linearity stays), the robot's path deviation as given."""
    return SimConfig.model_validate(
        {"seed": 6, "time_scale": time_scale, "robot": robot, "laser": {"noise_mm": 0.0}}
    )


def _aimed(cell: SimCell, x_T: float, y_T: float, standoff_mm: float) -> MotionRequest:
    """A move whose beam meets the nominal wall at (x_T, y_T) of T from ``standoff_mm`` (belief = aim)."""
    T_B_T = cell.world().T_B_T
    R = T_B_T[:3, :3] @ cell.T_H_C[:3, :3].T
    spot = T_B_T @ np.array([x_T, y_T, 0.0, 1.0])
    origin = spot[:3] - R @ (cell.laser_model.r + standoff_mm * cell.laser_model.l)
    return MotionRequest(CartesianPose.from_matrix(make_pose(R, origin)), speed_mm_s=SPEED_MM_S)


async def _scan(
    cell: SimCell, *, cycle_s: float = 0.001, count: int = 65535
) -> tuple[SimRobot, tuple[PoseSample, ...], StoredReadings]:
    """Feedback and storage over a diagonal pass: 80 mm towards the wall and 100 mm across into the opening."""
    robot, laser = SimRobot(cell), SimDisplacementSensor(cell)
    await robot.move(_aimed(cell, 60.0, 600.0, 380.0), timeout_s=T_OUT)
    await robot.start_stream(timeout_s=T_OUT)
    await laser.start_storage(cycle_s=cycle_s, count=count, timeout_s=T_OUT)
    # The flange stands 20 ms (five feedback periods) before the pass: the first samples are still
    # at rest however long the two calls above took on a loaded machine.
    await asyncio.sleep(0.02)
    await robot.move(_aimed(cell, -40.0, 600.0, 300.0), timeout_s=T_OUT)
    samples = await robot.stop_stream(timeout_s=T_OUT)
    stored = await laser.stop_storage(timeout_s=T_OUT)
    return robot, samples, stored


def test_devices_implement_the_onthefly_ports() -> None:
    cell = SimCell(_config())
    assert isinstance(SimRobot(cell), PoseStream)
    assert isinstance(SimDisplacementSensor(cell), StoringSensor)


@pytest.mark.parametrize("time_scale", [0.001, 0.0])
async def test_feedback_reports_the_path_at_true_instants_with_late_stamps(time_scale: float) -> None:
    cell = SimCell(_config(time_scale))
    rc = cell.config.robot
    robot, samples, _ = await _scan(cell)
    stamps = np.array([s.t_s for s in samples])
    assert len(samples) > 100 and np.all(np.diff(stamps) > 0)
    # Each sample's true instant lies on the controller's grid; its stamp is late by the latency +- jitter.
    phase, period = robot.feedback_phase_s, rc.feedback_period_s
    instants = phase + np.round((stamps - rc.feedback_latency_s - phase) / period) * period
    late = stamps - instants
    assert np.all(np.abs(late - rc.feedback_latency_s) <= rc.feedback_jitter_s + 1e-9)
    assert abs(late.mean() - rc.feedback_latency_s) < 0.3 * rc.feedback_jitter_s
    assert late.std() > 0.3 * rc.feedback_jitter_s  # the jitter is there
    np.testing.assert_allclose(np.diff(instants), rc.feedback_period_s, atol=1e-9)  # no sample lost
    shift = []
    for t, sample in zip(instants, samples, strict=True):
        np.testing.assert_allclose(sample.pose.to_matrix(), cell.arm.belief_at_line(t), atol=1e-6)
        at_stamp = cell.arm.belief_at_line(t + rc.feedback_latency_s)
        shift.append(np.linalg.norm(sample.pose.position_mm - at_stamp[:3, 3]))
    # The latency matters: at 500 mm/s the pose at the stamp is 0.5 mm off the sample.
    assert max(shift) == pytest.approx(SPEED_MM_S * rc.feedback_latency_s, rel=0.05)
    # Moving and resting show in the samples: the first and last stand still, the middle moves.
    positions = np.array([s.pose.position_mm for s in samples])
    assert np.linalg.norm(positions[1] - positions[0]) < 1e-9 and np.linalg.norm(positions[-1] - positions[-2]) < 1e-9
    assert np.linalg.norm(positions[-1] - positions[0]) > 100.0


@pytest.mark.parametrize("time_scale", [0.001, 0.0])
async def test_stored_readings_are_the_beam_at_the_true_flange_a_latency_earlier(time_scale: float) -> None:
    cell = SimCell(_config(time_scale))
    latency_s = cell.config.laser.storage_latency_s
    _, _, stored = await _scan(cell)
    assert stored.cycle_s == 0.001 and len(stored.distances_mm) > 300
    world, model = cell.world(), cell.laser_model
    shift = []
    for k, distance in enumerate(stored.distances_mm):
        instant = stored.started_s + k * stored.cycle_s
        status, expected = model.reading(cell.arm.true_at_line(instant - latency_s), world)
        assert distance == (None if expected is None else pytest.approx(expected, abs=1e-9)), (k, status)
        undelayed = model.true_distance(cell.arm.true_at_line(instant), world)
        if distance is not None and undelayed is not None:
            shift.append(abs(distance - undelayed))
    # Valid readings on the wall, then none through the opening; the 8 ms delay moves the beam by mm.
    assert stored.distances_mm[0] is not None and stored.distances_mm[-1] is None
    assert max(shift) > 0.4 * SPEED_MM_S * latency_s


async def test_storage_count_bounds_the_readings() -> None:
    cell = SimCell(_config())
    _, _, stored = await _scan(cell, cycle_s=0.002, count=25)
    assert len(stored.distances_mm) == 25 and stored.cycle_s == 0.002


def test_true_path_lags_and_deviates_sideways_more_at_speed() -> None:
    cell = SimCell(_config(0.0))
    arm, rc = cell.arm, cell.config.robot
    start = arm.belief_pose()
    deviation = {}
    for speed in (250.0, 500.0):
        target = start.copy()
        target[:3, 3] += [0.0, 400.0 if speed == 250.0 else -400.0, 0.0]
        motion = arm.start(target, speed)
        assert motion.timing is not None
        tau = motion.timing.path_s / 2.0  # cruising
        true = arm.true_at_line(motion.line_start + tau)
        nominal = motion.true_at_tau(tau, deviate=False)
        direction = (target[:3, 3] - start[:3, 3]) / 400.0
        along = (nominal[:3, 3] - true[:3, 3]) @ direction
        assert along == pytest.approx(speed * rc.path_lag_s, rel=1e-3)  # the true path is 0.5 mm off the belief
        lagged = motion.true_at_tau(tau - rc.path_lag_s, deviate=False)
        sideways = true[:3, 3] - lagged[:3, 3]
        assert np.linalg.norm(sideways) == pytest.approx(speed * rc.path_sideways_s, rel=1e-6)
        # Square to the path, to the clock's resolution (line_start + tau rounds at the monotonic clock's size).
        assert abs(sideways @ direction) < 1e-6 * np.linalg.norm(sideways)
        deviation[speed] = np.linalg.norm(true[:3, 3] - nominal[:3, 3])
        # Reported pose: the path without deviation; at rest the truth is the move's target exactly.
        np.testing.assert_allclose(arm.belief_at_line(motion.line_start + tau), motion.belief_at_tau(tau))
        np.testing.assert_array_equal(arm.true_at_line(motion.line_start + motion.duration_s), motion.target_true)
        start = arm.belief_pose()
    assert deviation[500.0] == pytest.approx(2.0 * deviation[250.0], rel=1e-3)


async def test_stop_and_go_figures_are_unchanged_by_the_deviation_at_speed() -> None:
    results = []
    for robot_cfg in ({}, {"path_lag_s": 0.0, "path_sideways_s": 0.0}):
        cell = SimCell(SimConfig.model_validate({"seed": 3, "robot": robot_cfg}))
        robot, laser = SimRobot(cell), SimDisplacementSensor(cell)
        reply = await robot.move(_aimed(cell, 100.0, 600.0, 330.0), timeout_s=T_OUT)
        reading = await laser.read(timeout_s=T_OUT)
        results.append((reply.to_matrix(), cell.true_flange_pose(), reading.distance_mm))
    (reply_a, true_a, d_a), (reply_b, true_b, d_b) = results
    np.testing.assert_array_equal(reply_a, reply_b)
    np.testing.assert_array_equal(true_a, true_b)
    assert d_a == d_b and d_a is not None


async def test_refusals_timeouts_and_closing() -> None:
    cell = SimCell(_config())
    robot, laser = SimRobot(cell), SimDisplacementSensor(cell)
    for cycle_s in (10e-6, 2.0):
        with pytest.raises(DeviceRejected, match="storage cycle"):
            await laser.start_storage(cycle_s=cycle_s, count=100, timeout_s=T_OUT)
    for count in (0, 65536):
        with pytest.raises(DeviceRejected, match="storage count"):
            await laser.start_storage(cycle_s=0.001, count=count, timeout_s=T_OUT)
    with pytest.raises(DeviceRejected, match="start_storage"):
        await laser.stop_storage(timeout_s=T_OUT)
    with pytest.raises(DeviceRejected, match="start_stream"):
        await robot.stop_stream(timeout_s=T_OUT)
    with pytest.raises(ValueError, match="timeout_s"):
        await laser.start_storage(cycle_s=0.001, count=10, timeout_s=0.0)
    started_s = await laser.start_storage(cycle_s=20e-6, count=65535, timeout_s=T_OUT)
    assert started_s == pytest.approx(cell.timeline.now(), abs=0.1)
    await laser.stop_storage(timeout_s=T_OUT)
    with pytest.raises(DeviceRejected, match="start_storage"):  # the storage was read out
        await laser.stop_storage(timeout_s=T_OUT)
    await robot.close()
    await laser.close()
    with pytest.raises(DeviceDisconnected):
        await robot.start_stream(timeout_s=T_OUT)
    with pytest.raises(DeviceDisconnected):
        await robot.stop_stream(timeout_s=T_OUT)
    with pytest.raises(DeviceDisconnected):
        await laser.start_storage(cycle_s=0.001, count=10, timeout_s=T_OUT)
    with pytest.raises(DeviceDisconnected):
        await laser.stop_storage(timeout_s=T_OUT)
    # In real time a round trip longer than the timeout is not answered.
    slow = SimCell(SimConfig.model_validate({"time_scale": 1.0, "laser": {"read_latency_s": 0.2}}))
    with pytest.raises(DeviceTimeout):
        await SimDisplacementSensor(slow).start_storage(cycle_s=0.001, count=10, timeout_s=0.01)
    with pytest.raises(DeviceTimeout):
        await SimRobot(slow).start_stream(timeout_s=0.001)


def test_the_true_path_follows_the_accuracy_field_along_the_way() -> None:
    """The arm's kinematic errors act at every point of a move, not only at its ends."""
    cell = SimCell(SimConfig.model_validate(
        {"seed": 6, "time_scale": 0.0, "robot": {"repeatability_mm": 0.0, "repeatability_orientation_deg": 0.0,
                                                 "path_lag_s": 0.0, "path_sideways_s": 0.0}}))  # fmt: skip
    arm = cell.arm
    start = arm.belief_pose()
    target = start.copy()
    target[:3, 3] += [0.0, 1500.0, 0.0]
    motion = arm.start(target, 500.0)
    assert motion.timing is not None
    tau = motion.timing.path_s / 2.0
    belief = motion.belief_at_tau(tau)
    true = arm.true_at_line(motion.line_start + tau)
    np.testing.assert_allclose(true, cell.robot_model.deform(belief), atol=1e-9)
    ends = interpolate_pose(motion.start_true, motion.target_true, motion.timing.fraction(tau))
    assert np.linalg.norm(true[:3, 3] - ends[:3, 3]) > 1e-3  # the field bends the path between the ends


async def test_reading_the_storage_out_takes_the_serial_line_not_the_twins_ray_casts(monkeypatch: pytest.MonkeyPatch) -> None:
    cell = SimCell(_config())
    laser, c = SimDisplacementSensor(cell), cell.config.laser
    await laser.start_storage(cycle_s=0.001, count=200, timeout_s=T_OUT)
    cell.timeline.waited(0.5)  # the robot stands while the laser stores: 200 readings
    cast = cell.laser_reading

    def slow_cast(*args: object) -> object:
        time.sleep(0.003)  # the twin's physics at its slowest: 0.6 s of ray casts for 200 readings
        return cast(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(cell, "laser_reading", slow_cast)
    before = cell.timeline.now()
    stored = await laser.stop_storage(timeout_s=T_OUT)
    spent = cell.timeline.now() - before
    assert len(stored.distances_mm) == 200
    # The cell waits for the stop's round trip and the read-out on the serial line, not for the ray casts
    # (the host's own scheduling counts at its real duration: a loaded machine adds a few ms).
    assert spent == pytest.approx(c.read_latency_s + 200 * c.readout_s_per_reading, abs=0.1)
