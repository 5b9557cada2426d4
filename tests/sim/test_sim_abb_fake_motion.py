"""The ABB fake moving the twin's arm in time (issue 19, on the move through the drivers): the arm is
truly on its way while the fake's move runs (the LK-G fake reads it there), the fake reports the arm's
own belief along the path (what the EGM stream sends), and a halt leaves both where the arm stopped."""

from __future__ import annotations

import time

import numpy as np
import pytest
from abb_robot.fake.robot import FakeRobot

from cellctl.config.sim import SimConfig
from cellctl.ports import CartesianPose
from cellctl.geometry.pose import make_pose
from cellctl.service.sim_fakes import TwinArmModel, TwinLaserSource
from cellctl.sim.cell import SimCell

pytestmark = pytest.mark.timeout(30)
SPEED_MM_S = 100.0


def _start(move_mm: float) -> tuple[SimCell, np.ndarray, FakeRobot, np.ndarray, float]:
    cell = SimCell(SimConfig(time_scale=1.0), seed=3)
    home = cell.belief_flange_pose()
    robot = FakeRobot(TwinArmModel(cell), CartesianPose.from_matrix(home), time_scale=1.0)
    robot.speed = (SPEED_MM_S, 30.0)
    target = home.copy()
    target[:3, 3] += [0.0, move_mm, 0.0]
    motion = robot.begin_motion(CartesianPose.from_matrix(target), linear=True)
    return cell, home, robot, target, motion.duration_s


def test_the_arm_is_on_its_way_while_the_fakes_move_runs() -> None:
    cell, home, robot, target, duration_s = _start(120.0)
    assert duration_s == pytest.approx(cell.motion_time(home, target, SPEED_MM_S, 30.0), rel=0.01)
    time.sleep(0.4 * duration_s)
    t0 = time.monotonic()
    reported = robot.flange().to_matrix()
    belief, true = cell.belief_flange_pose(), cell.true_flange_pose()
    read_s = time.monotonic() - t0  # the two reads' instants lie within this (a loaded machine may stretch it)
    # The fake reports the arm's own belief: the same to within the arm's travel between the two reads.
    assert np.linalg.norm(reported[:3, 3] - belief[:3, 3]) < 0.2 + SPEED_MM_S * read_s
    # Both are truly on the way: far from either end, where a move executed at once would stand.
    for pose in (reported, true):
        assert 20.0 < np.linalg.norm(pose[:3, 3] - target[:3, 3]) < 100.0
    time.sleep(0.7 * duration_s)
    assert np.allclose(cell.belief_flange_pose(), target, atol=1e-9) and not cell.arm.moving()


def test_a_halt_stops_the_arm_where_the_fake_says_it_stands() -> None:
    cell, home, robot, target, duration_s = _start(120.0)
    time.sleep(0.3 * duration_s)
    assert robot.halt() and not cell.arm.moving()
    stood = robot.flange().to_matrix()
    assert np.allclose(stood, cell.belief_flange_pose(), atol=1e-9)
    assert np.linalg.norm(stood[:3, 3] - target[:3, 3]) > 40.0  # stopped mid-path, not at the target
    time.sleep(0.8 * duration_s)  # past the move's planned end: nothing moves on
    assert np.allclose(cell.belief_flange_pose(), stood, atol=1e-9)


def test_the_lkg_fake_reads_the_arm_at_a_past_instant_though_the_time_line_stood_still_since() -> None:
    # The LK-G fake asks for a stored reading's distance after its instant; the twin's time line may
    # have stood still meanwhile (rendering), so the arm is looked up by its own clock (the fakes').
    cell = SimCell(SimConfig(time_scale=1.0), seed=3)
    sim, world = cell.config, cell.world()
    R = world.T_B_T[:3, :3] @ cell.T_H_C[:3, :3].T
    spot = world.T_B_T[:3, :3] @ np.array([100.0, 600.0, 0.0]) + world.T_B_T[:3, 3]
    start = make_pose(R, spot - R @ (sim.laser.r + 350.0 * sim.laser.l))
    target = make_pose(R, start[:3, 3] + 60.0 * (R @ sim.laser.l))  # 60 mm along the beam, toward the wall
    cell.execute(start)
    robot = FakeRobot(TwinArmModel(cell), CartesianPose.from_matrix(start), time_scale=1.0)
    robot.speed = (SPEED_MM_S, 30.0)
    source = TwinLaserSource(cell)
    before = source()
    duration_s = robot.begin_motion(CartesianPose.from_matrix(target), linear=True).duration_s
    time.sleep(0.4 * duration_s)
    t_a = time.monotonic()
    then = source()  # the distance now, read as the laser would
    t_b = time.monotonic()
    assert isinstance(before, float) and isinstance(then, float) and before - then > 10.0  # truly on its way
    with cell.timeline.unclocked():  # the twin computes: its clock stands still for 0.3 s
        time.sleep(0.3)
    later = source.at(0.5 * (t_a + t_b))
    assert isinstance(later, float)
    assert later == pytest.approx(then, abs=0.2 + SPEED_MM_S * (t_b - t_a))  # + the laser's noise
