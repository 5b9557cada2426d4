"""The fake controller in its own process (python -m abb_robot.fake), and the benchmark's CLI."""

from __future__ import annotations

import asyncio
import math
import subprocess
import sys

from _abb_testkit import LOOPBACK, free_udp_port
from abb_robot import AbbRobot, AbbRobotSettings
from cellctl.ports import CartesianPose, MotionRequest, UnreachableTarget

import pytest


async def _spawn(*args: str) -> tuple[asyncio.subprocess.Process, dict[str, str]]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "abb_robot.fake", *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )
    assert proc.stdout is not None
    line = (await asyncio.wait_for(proc.stdout.readline(), 20.0)).decode()
    assert line.startswith("READY "), line
    return proc, dict(f.split("=", 1) for f in line.split()[1:])


async def test_client_against_the_fake_in_its_own_process() -> None:
    egm_port = free_udp_port()
    proc, ready = await _spawn("--rapid-port", "0", "--egm-port", str(egm_port), "--time-scale", "0.05",
                               "--seed", "3", "--egm-loss", "0.05")
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=int(ready["rapid_port"]), egm_port=egm_port,
                                      egm_bind_host=LOOPBACK))
    try:
        assert ready["egm_port"] != "none"
        await robot.connect(timeout_s=5.0)
        start = await robot.read_pose(timeout_s=2.0)
        x, y, z = start.position_mm
        moved = await robot.move(MotionRequest(CartesianPose((x + 50.0, y, z), start.quaternion_wxyz)), timeout_s=5.0)
        assert math.dist(moved.position_mm, (x + 50.0, y, z)) < 0.3
        with pytest.raises(UnreachableTarget):
            await robot.move(MotionRequest(CartesianPose((x + 2000.0, y, z), start.quaternion_wxyz)), timeout_s=5.0)
        target = CartesianPose((x + 52.0, y + 1.0, z), start.quaternion_wxyz)
        got = await robot.correct_to(target, tolerance_mm=0.1, tolerance_rad=0.001, timeout_s=5.0)
        assert math.dist(got.position_mm, target.position_mm) <= 0.1
        assert robot.egm.stats().sessions == 1  # type: ignore[union-attr]
    finally:
        await robot.close()
        proc.terminate()
        assert await asyncio.wait_for(proc.wait(), 10.0) == 0


def test_fake_cli_refuses_bad_arguments() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "abb_robot.fake", "--rapid-port", "0", "--egm-port", "1", "--egm-loss", "1.5"],
        capture_output=True, text=True, timeout=30,
    )
    assert out.returncode == 2 and "loss_out must be in [0, 1)" in out.stderr


def test_benchmark_runs_and_prints_its_figures() -> None:
    out = subprocess.run([sys.executable, "-m", "abb_robot.bench", "--seconds", "1"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "reply latency at the peer" in out.stdout and "reply latency at the controller" in out.stdout
    assert "Hz" in out.stdout and "missed cycles" in out.stdout
