"""GRIP, the gripper's vacuum, over the real wire: the fake controller byte by byte, then AbbRobot."""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import AsyncIterator
from types import SimpleNamespace

import pytest

from _abb_testkit import LOOPBACK, ScriptedController, fake_and_robot, hello_then, settings_for, start_fake
from abb_robot import AbbRobot
from abb_robot.fake import DEFAULT_HOME, FakeController
from cellctl.ports import CartesianPose, DeviceProtocolError, DeviceRejected, DeviceTimeout, MotionRequest

pytestmark = pytest.mark.timeout(60)


class _Calls:
    """The fake's on_gripper physics: records each call and the thread it came from."""

    def __init__(self, fail: bool = False) -> None:
        self.values: list[bool] = []
        self.threads: list[str] = []
        self.fail = fail

    def __call__(self, hold: bool) -> None:
        if self.fail:
            raise RuntimeError("twin refused")
        self.values.append(hold)
        self.threads.append(threading.current_thread().name)


@contextlib.asynccontextmanager
async def _lines(fake: FakeController) -> AsyncIterator[tuple[asyncio.StreamReader, asyncio.StreamWriter]]:
    reader, writer = await asyncio.open_connection(LOOPBACK, fake.rapid_port)
    try:
        yield reader, writer
    finally:
        writer.close()


async def _ask(conn: tuple[asyncio.StreamReader, asyncio.StreamWriter], line: str, n: int = 1) -> list[str]:
    reader, writer = conn
    writer.write((line + "\n").encode())
    await writer.drain()
    out = []
    for _ in range(n):
        raw = await asyncio.wait_for(reader.readline(), 3.0)
        assert raw.endswith(b"\n") and len(raw) <= 80, raw
        out.append(raw.decode().rstrip("\n"))
    return out


def _target(dx: float) -> CartesianPose:
    x, y, z = DEFAULT_HOME.position_mm
    return CartesianPose((x + dx, y, z), DEFAULT_HOME.quaternion_wxyz)


async def test_grip_on_the_wire_switches_the_output_and_tells_the_physics() -> None:
    calls = _Calls()
    fake = start_fake(time_scale=0.05, gripper_hold=True, on_gripper=calls)
    try:
        assert fake.gripper_hold
        async with _lines(fake) as c:
            assert await _ask(c, "1 GRIP 0") == ["1 ERR 103 send HELLO first"]
            assert (await _ask(c, "2 HELLO 1"))[0].startswith("2 OK 1 ")
            assert await _ask(c, "3 GRIP 0") == ["3 OK 0"]
            assert not fake.gripper_hold
            assert await _ask(c, "4 GRIP 0") == ["4 OK 0"]  # switching to the same state again is harmless
            assert await _ask(c, "5 grip 1") == ["5 OK 1"]
            assert fake.gripper_hold
            assert await _ask(c, "6 GRIP 2") == ["6 ERR 122 GRIP needs 0 (release) or 1 (hold)"]
            assert await _ask(c, "7 GRIP 1.0") == ["7 ERR 100 hold is not an integer"]
            assert await _ask(c, "8 GRIP") == ["8 ERR 100 GRIP takes 1 args, got 0"]
            assert await _ask(c, "9 GRIP x") == ["9 ERR 100 argument 1 is not a decimal number"]
            assert await _ask(c, "10 STATE") == ["10 OK 1 0"]  # STATE is unchanged by the gripper
        assert calls.values == [False, False, True]
        # Called from the controller's own thread, as the model's execute/motion_time are.
        assert set(calls.threads) == {"fake-abb-controller"}
        assert fake.gripper_hold
    finally:
        fake.stop_thread()


async def test_grip_is_refused_while_moving_and_the_output_keeps_its_value() -> None:
    calls = _Calls()
    fake = start_fake(time_scale=1.0, gripper_hold=True, on_gripper=calls)
    try:
        async with _lines(fake) as c:
            await _ask(c, "1 HELLO 1")
            await _ask(c, "2 SPEED 50 30")
            await _ask(c, "3 POS 2100 0 1500")
            await _ask(c, "4 ORI 0.7071068 0 0.7071068 0")
            assert await _ask(c, "5 MOVEL") == ["5 ACK"]  # about 2 s
            assert await _ask(c, "6 GRIP 0") == ["6 ERR 110 GRIP refused: a motion is running"]
            assert await _ask(c, "7 GRIP 1") == ["7 ERR 110 GRIP refused: a motion is running"]
            assert fake.gripper_hold and calls.values == []
            assert await _ask(c, "8 STOP", 2) == ["8 OK 1", "5 ERR 140 motion stopped"]
            assert await _ask(c, "9 GRIP 0") == ["9 OK 0"]  # at a standstill it goes through
        assert calls.values == [False] and not fake.gripper_hold
    finally:
        fake.stop_thread()


async def test_grip_answers_after_the_settle_time_and_reads_nothing_meanwhile() -> None:
    fake = start_fake(time_scale=1.0, gripper_settle_s=0.3)
    try:
        async with _lines(fake) as c:
            await _ask(c, "1 HELLO 1")
            reader, writer = c
            t0 = time.monotonic()
            writer.write(b"2 GRIP 1\n3 PING\n")
            await writer.drain()
            first = (await asyncio.wait_for(reader.readline(), 3.0)).decode().rstrip("\n")
            settled = time.monotonic() - t0
            second = (await asyncio.wait_for(reader.readline(), 3.0)).decode().rstrip("\n")
        assert (first, second) == ("2 OK 1", "3 PONG")  # the PING waited for the settle, as in RAPID
        assert 0.28 <= settled < 2.0
    finally:
        fake.stop_thread()


async def test_failing_physics_is_an_io_error_and_the_output_stays() -> None:
    fake = start_fake(time_scale=0.05, gripper_hold=True, on_gripper=_Calls(fail=True))
    try:
        async with _lines(fake) as c:
            await _ask(c, "1 HELLO 1")
            assert await _ask(c, "2 GRIP 0") == ["2 ERR 160 gripper output error RuntimeError"]
        assert fake.gripper_hold
    finally:
        fake.stop_thread()


# ---------------------------------------------------------------------------------------------
# AbbRobot.set_gripper


async def test_client_set_gripper_round_trip() -> None:
    calls = _Calls()
    async with fake_and_robot(fake_kw={"gripper_hold": True, "on_gripper": calls}) as (fake, robot):
        await robot.set_gripper(False, timeout_s=2.0)
        assert not fake.gripper_hold
        await robot.set_gripper(True, timeout_s=2.0)
        assert fake.gripper_hold
        assert calls.values == [False, True]
        assert [line.split(" ", 1)[1] for line in fake.server.lines_received if " GRIP " in line] == [
            "GRIP 0", "GRIP 1",
        ]
        with pytest.raises(TypeError, match="True or False"):
            await robot.set_gripper(1, timeout_s=2.0)  # type: ignore[arg-type]


async def test_client_release_while_moving_is_refused_clearly() -> None:
    calls = _Calls()
    async with fake_and_robot(fake_kw={"time_scale": 1.0, "gripper_hold": True, "on_gripper": calls}) as (fake, robot):
        move = asyncio.create_task(robot.move(MotionRequest(_target(100.0), speed_mm_s=50.0), timeout_s=10.0))
        await asyncio.sleep(0.3)
        with pytest.raises(DeviceRejected) as info:
            await robot.set_gripper(False, timeout_s=1.0)
        assert info.value.code == "110 BUSY"
        assert str(info.value) == (
            "robot: gripper release refused: the robot is moving; the gripper keeps its state "
            "(switch it only at a standstill) (code 110 BUSY)"
        )
        assert fake.gripper_hold and calls.values == []
        await asyncio.wait_for(move, 5.0)
        await robot.set_gripper(False, timeout_s=2.0)  # after the move: released
        assert calls.values == [False]


async def test_a_settle_longer_than_the_heartbeat_keeps_the_link() -> None:
    # The module reads nothing while the gripper settles; the heartbeat (PING after 0.3 s quiet, PONG
    # within 0.5 s) must leave the link alone while GRIP waits for its answer, or the settle drops it.
    async with fake_and_robot(fake_kw={"time_scale": 1.0, "gripper_settle_s": 1.5}) as (fake, robot):
        for hold in (True, False):
            await robot.set_gripper(hold, timeout_s=4.0)
            assert fake.gripper_hold is hold
        assert robot.connections == 1
        assert await robot.ping(timeout_s=1.0) >= 0.0


async def test_client_timeout_when_the_settle_outlasts_it() -> None:
    async with fake_and_robot(fake_kw={"time_scale": 1.0, "gripper_settle_s": 0.8}) as (fake, robot):
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match=r"gripper release \(GRIP 0\) not confirmed within 0.2 s"):
            await robot.set_gripper(False, timeout_s=0.2)
        assert time.monotonic() - t0 < 0.6  # bounded by the timeout, not by the settle
        assert not fake.gripper_hold  # it did switch: the timeout says the state is unknown
        await asyncio.sleep(0.8)  # the late OK is dropped; the link goes on
        assert await robot.ping(timeout_s=1.0) >= 0.0
        await robot.set_gripper(True, timeout_s=2.0)
        assert fake.gripper_hold


async def test_client_io_error_and_bad_echo() -> None:
    async with fake_and_robot(fake_kw={"on_gripper": _Calls(fail=True)}) as (_fake, robot):
        with pytest.raises(DeviceRejected, match=r"GRIP refused: gripper output error RuntimeError \(code 160 GRIPPER\)"):
            await robot.set_gripper(True, timeout_s=2.0)
    ctl = ScriptedController(hello_then(lambda rid, verb, args: [f"{rid} OK 7\n".encode()] if verb == "GRIP" else None))
    port = await ctl.start()
    robot = AbbRobot(settings_for(SimpleNamespace(rapid_port=port), heartbeat_period_s=5.0))  # type: ignore[arg-type]
    try:
        await robot.connect(timeout_s=2.0)
        with pytest.raises(DeviceProtocolError, match="bad GRIP answer: '7'"):
            await robot.set_gripper(True, timeout_s=1.0)
    finally:
        await robot.close()
        await ctl.close()
