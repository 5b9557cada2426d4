"""How the ABB client reads the controller's answers: rules no other test pinned down (a mutation run found
them unguarded).

Facts (drivers/abb_robot/README.md, "The line protocol", its verb and code tables, and "The client"):

- ``HELLO version`` is answered ``OK version robot_type rw_version``; the protocol version must match.
- ``GETJ`` is answered ``OK j1 j2 j3 j4 j5 j6`` (six angles, degrees).
- ``STATE`` is answered ``OK motors moving``: motors 1 on, 0 off, -1 unknown (no signal configured), and
  "without it, motors are reported as unknown, -1, and cellctl's ``RobotState.motors_on`` is False".
- ``GRIP hold`` is answered ``OK hold``.
- request ids are 1..99999, chosen by the client.
- errors become ``UnreachableTarget`` (130, 131), ``MotionInterrupted`` (140, 141, 150, 152) or
  ``DeviceRejected`` with the code, e.g. ``(code 110 BUSY)``.

The controller is a scripted TCP peer on 127.0.0.1 writing literal reply bytes (it stands in for one that
answers out of the protocol, which the fake never does).
"""

from __future__ import annotations

import math
import time
from collections.abc import Awaitable, Callable
from typing import TypeVar

import pytest

from _abb_testkit import LOOPBACK, scripted_robot
from abb_robot import AbbRobot, AbbRobotSettings
from abb_robot import protocol as P
from abb_robot.link import RapidLink
from cellctl.ports import (
    CartesianPose,
    DeviceProtocolError,
    DeviceRejected,
    MotionInterrupted,
    MotionRequest,
    UnreachableTarget,
)

Respond = Callable[[int, str, list[str]], "list[bytes] | None"]
T = TypeVar("T")


async def _with(respond: Respond, call: Callable[[AbbRobot], Awaitable[T]]) -> tuple[T, list[str]]:
    """Run ``call(robot)`` against a scripted controller; returns what it returned and the lines it received."""
    async with scripted_robot(respond) as (robot, ctl):
        return await call(robot), ctl.received


async def test_a_hello_answer_with_another_protocol_version_is_refused() -> None:
    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        return [f"{rid} OK 2 TEST_ROBOT RW_TEST\n".encode()] if verb == "HELLO" else None

    async with scripted_robot(respond, connect=False) as (robot, ctl):
        with pytest.raises(DeviceProtocolError, match="HELLO"):
            await robot.connect(timeout_s=2.0)
        assert ctl.received[0] == "1 HELLO 1"
        assert not robot.connected


async def test_a_getj_answer_with_seven_angles_is_malformed() -> None:
    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        return [f"{rid} OK 1 2 3 4 5 6 7\n".encode()] if verb == "GETJ" else None

    async def call(robot: AbbRobot) -> None:
        with pytest.raises(DeviceProtocolError, match="GETJ"):
            await robot.read_joints(timeout_s=2.0)

    await _with(respond, call)


async def test_six_angles_in_degrees_are_read_in_radians() -> None:
    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        return [f"{rid} OK 90 -45.5 0 180 1.2345 -359.9999\n".encode()] if verb == "GETJ" else None

    async def call(robot: AbbRobot) -> tuple[float, ...]:
        return await robot.read_joints(timeout_s=2.0)

    joints, _ = await _with(respond, call)
    assert joints == pytest.approx(tuple(math.radians(v) for v in (90, -45.5, 0, 180, 1.2345, -359.9999)))


@pytest.mark.parametrize(("motors", "on"), [("1", True), ("0", False), ("-1", False)])
async def test_motors_unknown_is_reported_as_off(motors: str, on: bool) -> None:
    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        if verb == "STATE":
            return [f"{rid} OK {motors} 0\n".encode()]
        if verb == "GETJ":
            return [f"{rid} OK 0 0 0 0 0 0\n".encode()]
        return None

    async def call(robot: AbbRobot) -> bool:
        return (await robot.state(timeout_s=2.0)).motors_on

    motors_on, _ = await _with(respond, call)
    assert motors_on is on


@pytest.mark.parametrize(("hold", "answer"), [(True, "0"), (False, "1"), (True, "")])
async def test_a_grip_answer_that_does_not_echo_the_request_is_malformed(hold: bool, answer: str) -> None:
    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        return [f"{rid} OK {answer}".rstrip().encode() + b"\n"] if verb == "GRIP" else None

    async def call(robot: AbbRobot) -> None:
        with pytest.raises(DeviceProtocolError, match="GRIP"):
            await robot.set_gripper(hold, timeout_s=2.0)

    _, received = await _with(respond, call)
    assert [line.split(" ", 1)[1] for line in received if " GRIP " in line] == [f"GRIP {1 if hold else 0}"]


async def test_request_ids_wrap_from_99999_to_1() -> None:
    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        return [f"{rid} OK 1 0\n".encode()] if verb == "STATE" else None

    async def call(robot: AbbRobot) -> None:
        robot._link._next_id = P.MAX_REQUEST_ID - 2  # noqa: SLF001 - the last id given was 99997
        for _ in range(3):
            lines = await robot._request("STATE", deadline=time.monotonic() + 2.0)  # noqa: SLF001
            assert lines[-1].fields == ("1", "0")

    _, received = await _with(respond, call)
    assert [line for line in received if line.endswith(" STATE")] == ["99998 STATE", "99999 STATE", "1 STATE"]


@pytest.mark.parametrize(
    ("code", "error"),
    [
        (130, UnreachableTarget), (131, UnreachableTarget),
        (140, MotionInterrupted), (141, MotionInterrupted), (150, MotionInterrupted), (152, MotionInterrupted),
        (110, DeviceRejected), (111, DeviceRejected), (122, DeviceRejected), (151, DeviceRejected),
    ],
)  # fmt: skip
async def test_a_motion_ending_in_err_raises_the_type_its_code_names(code: int, error: type[Exception]) -> None:
    """MOVEL is answered ACK, then ERR <code>: the README's mapping of codes to errors."""

    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        if verb in ("POS", "ORI"):
            return [f"{rid} OK\n".encode()]
        if verb == "MOVEL":
            return [f"{rid} ACK\n".encode(), f"{rid} ERR {code} scripted failure\n".encode()]
        return None

    async def call(robot: AbbRobot) -> None:
        target = CartesianPose((1000.0, 0.0, 1500.0), (1.0, 0.0, 0.0, 0.0))
        with pytest.raises(error) as info:
            await robot.move(MotionRequest(target, "linear", 100.0, 30.0), timeout_s=2.0)
        assert type(info.value) is error
        if isinstance(info.value, DeviceRejected):
            assert info.value.code == f"{code} {P.ErrorCode(code).name}"

    await _with(respond, call)


async def test_rapid_link_is_what_maps_the_codes() -> None:
    async def nothing(_deadline: float) -> None:
        return None

    link = RapidLink(AbbRobotSettings(host=LOOPBACK), name="robot", on_connect=nothing)
    assert isinstance(link.error("MOVEL", P.parse_reply("5 ERR 131 axis 5 beyond its limit")), UnreachableTarget)
    assert isinstance(link.error("EGM", P.parse_reply("5 ERR 152 supervision")), MotionInterrupted)
