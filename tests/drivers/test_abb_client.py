"""AbbRobot against the fake controller (and against scripted misbehaving ones), over loopback."""

from __future__ import annotations

import asyncio
import math
import time

import numpy as np
import pytest

from _abb_testkit import LOOPBACK, ScriptedController, fake_and_robot, hello_then, settings_for, start_fake
from abb_robot import AbbRobot, AbbRobotSettings
from abb_robot.fake import DEFAULT_HOME
from cellctl.ports import (
    CartesianPose,
    DeviceDisconnected,
    DeviceProtocolError,
    DeviceRejected,
    DeviceTimeout,
    FineCorrection,
    MotionInterrupted,
    MotionRequest,
    Robot,
    UnreachableTarget,
)

Q = DEFAULT_HOME.quaternion_wxyz
T_LOOPBACK = 5.0  # seconds for a loopback round trip to the fake controller, whatever the load


def _target(dx: float = 0.0, dy: float = 0.0, dz: float = 0.0, q: tuple[float, ...] = Q) -> CartesianPose:
    x, y, z = DEFAULT_HOME.position_mm
    return CartesianPose((x + dx, y + dy, z + dz), q)  # type: ignore[arg-type]


def test_implements_the_ports() -> None:
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=1, egm_port=None))
    assert isinstance(robot, Robot) and isinstance(robot, FineCorrection)


async def test_handshake_resync_and_queries() -> None:
    async with fake_and_robot() as (fake, robot):
        assert robot.info is not None and robot.info.robot_type == "IRB 7600-325/3.1"
        lines = [l.split(" ", 1)[1] for l in fake.server.lines_received]  # type: ignore[union-attr]
        assert lines[:5] == ["HELLO 1", "TOOL tool0", "WOBJ wobj0", "SPEED 100.000 30.000", "ZONE 0.000"]
        pose = await robot.read_pose(timeout_s=1.0)
        assert pose.position_mm == DEFAULT_HOME.position_mm
        joints = await robot.read_joints(timeout_s=1.0)
        assert np.allclose(joints, fake.model.joints(DEFAULT_HOME), atol=math.radians(1e-4))
        state = await robot.state(timeout_s=1.0)
        assert state.motors_on and state.program_running and not state.moving and len(state.joints_rad) == 6
        assert 0.0 < await robot.ping(timeout_s=1.0) < 1.0
        await robot.stop(timeout_s=1.0)  # nothing running: harmless


async def test_linear_and_joint_moves_reach_their_targets() -> None:
    async with fake_and_robot() as (fake, robot):
        got = await robot.move(MotionRequest(_target(dx=150.0, dz=-40.0), speed_mm_s=400.0), timeout_s=5.0)
        assert np.allclose(got.position_mm, _target(dx=150.0, dz=-40.0).position_mm, atol=0.2)  # repeatability
        assert fake.robot.speed == (400.0, 30.0)
        q2 = (0.6963642, 0.1227878, 0.6963642, -0.1227878)  # turned about the tool axis
        got = await robot.move(MotionRequest(_target(dy=80.0, q=q2), kind="joint"), timeout_s=5.0)
        assert np.allclose(got.position_mm, _target(dy=80.0).position_mm, atol=0.2)
        assert "MOVEJ" in " ".join(fake.server.lines_received)  # type: ignore[union-attr]


async def test_settings_verbs_and_typed_refusals() -> None:
    # The refusals are the point, not the round trip: a loaded machine once took over 1 s for the first SPEED.
    async with fake_and_robot() as (fake, robot):
        await robot.set_speed(250.0, 40.0, timeout_s=T_LOOPBACK)
        await robot.set_zone(0.0, timeout_s=T_LOOPBACK)
        await robot.set_tool("tool0", timeout_s=T_LOOPBACK)
        await robot.set_wobj("wobj0", timeout_s=T_LOOPBACK)
        with pytest.raises(DeviceRejected, match=r"no tooldata tGhost \(code 120 UNKNOWN_TOOL\)") as info:
            await robot.set_tool("tGhost", timeout_s=T_LOOPBACK)
        assert info.value.code == "120 UNKNOWN_TOOL"
        with pytest.raises(DeviceRejected, match="121 UNKNOWN_WOBJ"):
            await robot.set_wobj("wGhost", timeout_s=T_LOOPBACK)
        with pytest.raises(DeviceRejected, match="122 RANGE"):
            await robot.set_zone(5000.0, timeout_s=T_LOOPBACK)
        with pytest.raises(DeviceRejected, match="122 RANGE"):
            await robot.set_tool("no good", timeout_s=T_LOOPBACK)


async def test_unreachable_targets_raise_unreachable_target() -> None:
    async with fake_and_robot() as (fake, robot):
        with pytest.raises(UnreachableTarget, match="reach sphere") as info:
            await robot.move(MotionRequest(_target(dx=1800.0)), timeout_s=3.0)
        assert info.value.code == "130 REACH"
        back = (0.7071068, 0.0, -0.7071068, 0.0)
        with pytest.raises(UnreachableTarget, match="axis 5") as info:
            await robot.move(MotionRequest(_target(q=back)), timeout_s=3.0)
        assert info.value.code == "131 JOINT_LIMIT"
        assert fake.robot.flange() == DEFAULT_HOME  # nothing moved


async def test_motion_failure_is_interrupted_with_its_code() -> None:
    async with fake_and_robot() as (fake, robot):
        fake.set_motors(False)
        with pytest.raises(MotionInterrupted, match=r"motors are off \(code 141 MOTION\)"):
            await robot.move(MotionRequest(_target(dx=10.0)), timeout_s=3.0)
        state = await robot.state(timeout_s=1.0)
        assert not state.motors_on


async def test_stop_interrupts_a_move_and_busy_is_typed() -> None:
    async with fake_and_robot(fake_kw={"time_scale": 1.0}) as (fake, robot):
        move = asyncio.create_task(robot.move(MotionRequest(_target(dx=100.0), speed_mm_s=50.0), timeout_s=10.0))
        await asyncio.sleep(0.3)
        with pytest.raises(DeviceRejected, match="110 BUSY"):
            await robot.set_speed(10.0, 10.0, timeout_s=1.0)
        state = await robot.state(timeout_s=1.0)
        assert state.moving
        await robot.stop(timeout_s=1.0)
        with pytest.raises(MotionInterrupted, match=r"motion stopped \(code 140 STOPPED\)"):
            await asyncio.wait_for(move, 2.0)
        x = fake.robot.flange().position_mm[0]
        assert 2000.0 < x < 2090.0


async def test_move_timeout_stops_the_robot_and_never_hangs() -> None:
    async with fake_and_robot(fake_kw={"time_scale": 1.0}) as (fake, robot):
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match="not done in time; a STOP was sent"):
            await robot.move(MotionRequest(_target(dx=100.0), speed_mm_s=20.0), timeout_s=0.5)
        assert time.monotonic() - t0 < 2.5  # bounded by the timeout, not hung
        await asyncio.sleep(0.1)
        assert not fake.robot.moving


async def test_connection_dropped_mid_move_then_reconnect_with_resync() -> None:
    async with fake_and_robot(fake_kw={"time_scale": 1.0}) as (fake, robot):
        await robot.set_tool("tool0", timeout_s=1.0)
        move = asyncio.create_task(robot.move(MotionRequest(_target(dx=100.0), speed_mm_s=60.0), timeout_s=10.0))
        await asyncio.sleep(0.3)
        n_before = len(fake.server.lines_received)  # type: ignore[union-attr]
        fake.drop_client()
        with pytest.raises(MotionInterrupted, match="link lost during the motion"):
            await asyncio.wait_for(move, 2.0)
        await asyncio.sleep(0.1)
        assert not fake.robot.moving  # the controller stops a motion whose client is gone
        stopped_at = fake.robot.flange().position_mm[0]
        assert 2000.0 < stopped_at < 2095.0
        pose = await robot.read_pose(timeout_s=3.0)  # reconnects on demand
        assert pose.position_mm[0] == pytest.approx(stopped_at, abs=1e-3)
        assert robot.connections == 2
        after = [l.split(" ", 1)[1] for l in fake.server.lines_received[n_before:]]  # type: ignore[union-attr]
        assert after[:5] == ["HELLO 1", "TOOL tool0", "WOBJ wobj0", "SPEED 60.000 30.000", "ZONE 0.000"]


async def test_heartbeat_reconnects_in_the_background() -> None:
    async with fake_and_robot() as (fake, robot):
        fake.drop_client()
        deadline = time.monotonic() + 3.0
        while robot.connections < 2 and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        assert robot.connections == 2 and robot.connected
        pings = [l for l in fake.server.lines_received if l.endswith(" PING")]  # type: ignore[union-attr]
        await asyncio.sleep(0.8)
        assert len([l for l in fake.server.lines_received if l.endswith(" PING")]) > len(pings)  # type: ignore[union-attr]


async def test_silent_controller_gives_timeouts_not_hangs() -> None:
    async with fake_and_robot() as (fake, robot):
        fake.set_silent(True)
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match="GETC: no answer from the controller in time"):
            await robot.read_pose(timeout_s=0.4)
        assert time.monotonic() - t0 < 2.0  # bounded by the timeout, not hung
        deadline = time.monotonic() + 3.0
        while robot.connected and time.monotonic() < deadline:  # the heartbeat gives up on it
            await asyncio.sleep(0.05)
        assert not robot.connected
        fake.set_silent(False)
        pose = await robot.read_pose(timeout_s=5.0)
        assert pose.position_mm == DEFAULT_HOME.position_mm


async def test_controller_that_never_answers_hello() -> None:
    ctl = ScriptedController(lambda line: [])
    port = await ctl.start()
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=port, egm_port=None))
    try:
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match="HELLO"):
            await robot.connect(timeout_s=0.5)
        assert time.monotonic() - t0 < 2.0  # bounded by the timeout, not hung
    finally:
        await robot.close()
        await ctl.close()


async def test_refused_connection_is_disconnected() -> None:
    fake = start_fake()
    port = fake.rapid_port
    fake.stop_thread()
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=port, egm_port=None))  # type: ignore[arg-type]
    with pytest.raises(DeviceDisconnected, match="is the RAPID server running"):
        await robot.connect(timeout_s=1.0)
    await robot.close()


async def test_version_mismatch_is_rejected() -> None:
    ctl = ScriptedController(
        hello_then(lambda rid, verb, args: [f"{rid} ERR 102 version 1 not supported, server speaks 2\n".encode()]
                   if verb == "HELLO" else None)
    )
    port = await ctl.start()
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=port, egm_port=None))
    try:
        with pytest.raises(DeviceRejected, match="102 VERSION"):
            await robot.connect(timeout_s=1.0)
    finally:
        await robot.close()
        await ctl.close()


@pytest.mark.parametrize(
    ("answer", "match"),
    [
        (b"complete garbage\n", "malformed line"),
        (b"{rid} OK " + b"1" * 90 + b"\n", "80-byte"),
        (b"{rid} PONG\n", "unexpected PONG reply to GETC"),
        (b"{rid} DATA POS 1 2\n{rid} OK ORI 1 0 0 0\n", "bad GETC answer"),
        (b"{rid} OK ORI 1 0 0 0\n", "bad GETC answer"),
        (b"x" * 1100, "without a newline"),
    ],
)
async def test_malformed_lines_from_the_controller(answer: bytes, match: str) -> None:
    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        if verb == "GETC":
            return [answer.replace(b"{rid}", str(rid).encode())]
        return None

    ctl = ScriptedController(hello_then(respond))
    port = await ctl.start()
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=port, egm_port=None, heartbeat_period_s=5.0))
    try:
        await robot.connect(timeout_s=1.0)
        with pytest.raises(DeviceProtocolError, match=match):
            await robot.read_pose(timeout_s=1.0)
        assert await robot.ping(timeout_s=1.0) >= 0.0  # usable again (reconnected if it had to)
    finally:
        await robot.close()
        await ctl.close()


async def test_late_replies_are_ignored() -> None:
    held: list[bytes] = []

    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        if verb == "GETJ":
            held.append(f"{rid} OK 1 2 3 4 5 6\n".encode())  # answered only with the next request
            return []
        if verb == "STATE":
            return [*held, f"{rid} OK 1 0\n".encode()]
        return None

    ctl = ScriptedController(hello_then(respond))
    port = await ctl.start()
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=port, egm_port=None, heartbeat_period_s=5.0))
    try:
        await robot.connect(timeout_s=1.0)
        with pytest.raises(DeviceTimeout):
            await robot.read_joints(timeout_s=0.2)
        state_lines = await robot._request("STATE", deadline=time.monotonic() + 1.0)  # noqa: SLF001
        assert state_lines[-1].fields == ("1", "0")  # the stale GETJ answer did not take its place
    finally:
        await robot.close()
        await ctl.close()


def test_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="host"):
        AbbRobotSettings(host="")
    with pytest.raises(ValueError, match="rapid_port"):
        AbbRobotSettings(host=LOOPBACK, rapid_port=0)
    with pytest.raises(ValueError, match="heartbeat_timeout_s"):
        AbbRobotSettings(host=LOOPBACK, heartbeat_timeout_s=float("nan"))
    with pytest.raises(ValueError, match="RAPID name"):
        AbbRobotSettings(host=LOOPBACK, tool="my tool")
    with pytest.raises(ValueError, match="egm_cond_time_s"):
        AbbRobotSettings(host=LOOPBACK, egm_cond_time_s=0.0)


async def test_bad_timeouts_are_refused_before_any_io() -> None:
    fake = start_fake()
    robot = AbbRobot(settings_for(fake))
    try:
        with pytest.raises(ValueError, match="timeout_s"):
            await robot.read_pose(timeout_s=0.0)
        with pytest.raises(ValueError, match="timeout_s"):
            await robot.ping(timeout_s=float("inf"))
    finally:
        await robot.close()
        fake.stop_thread()
