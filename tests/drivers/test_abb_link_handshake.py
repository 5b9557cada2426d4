"""A connection of the ABB link is the live one only after its HELLO and settings (TOOL, WOBJ, SPEED, ZONE):
a call cancelled during them (an operator's Hold cancels the cycle task while its move reconnects) or a close()
meanwhile leaves no half-made connection behind, and the next call connects afresh and sends the settings."""

from __future__ import annotations

import asyncio
import time

import pytest

from _abb_testkit import LOOPBACK, ScriptedController, hello_then
from abb_robot import AbbRobot, AbbRobotSettings
from abb_robot import protocol as P
from cellctl.ports import CartesianPose, DeviceDisconnected, MotionRequest

pytestmark = pytest.mark.timeout(60)
SETTINGS = ["TOOL tGripper", "WOBJ wobj0", "SPEED 50.000 30.000", "ZONE 0.000"]  # what _robot() configures
POSE = CartesianPose((1.0, 2.0, 3.0), (1.0, 0.0, 0.0, 0.0))


class _Controller:
    """A scripted controller that records each connection's lines and leaves ``held`` requests of the
    first connection unanswered (a controller busy after its restart)."""

    def __init__(self, held: str | None) -> None:
        self.held = held
        self.lines: dict[int, list[str]] = {}
        self.ctl = ScriptedController(hello_then(self._answer))

    def _answer(self, rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        n = self.ctl.connections
        self.lines.setdefault(n, []).append(" ".join([verb, *args]))
        if n == 1 and verb == self.held:
            return []
        if verb in ("POS", "ORI"):
            return [P.format_reply(rid, P.Status.OK)]
        if verb in ("MOVEL", "MOVEJ"):
            return [P.format_reply(rid, P.Status.ACK), P.format_reply(rid, P.Status.DONE)]
        if verb == "GETC":
            return [P.format_reply(rid, P.Status.DATA, "POS", "1.000", "2.000", "3.000"),
                    P.format_reply(rid, P.Status.OK, "ORI", "1.000000", "0.000000", "0.000000", "0.000000")]  # fmt: skip
        return None

    async def wait_for_line(self, connection: int, line: str) -> None:
        deadline = time.monotonic() + 5.0
        while line not in self.lines.get(connection, []):
            assert time.monotonic() < deadline, f"the controller never got {line!r}: {self.lines}"
            await asyncio.sleep(0.01)


def _robot(port: int) -> AbbRobot:
    return AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=port, egm_port=None, tool="tGripper", speed_mm_s=50.0,
                                     speed_deg_s=30.0, zone_mm=0.0))  # fmt: skip


@pytest.mark.parametrize("held", ["HELLO 1", "SPEED 50.000 30.000"], ids=["during-HELLO", "during-the-settings"])
async def test_a_call_cancelled_during_the_handshake_leaves_no_connection(held: str) -> None:
    c = _Controller(held.split(" ")[0])
    port = await c.ctl.start()
    robot = _robot(port)
    try:
        first = asyncio.create_task(robot.read_pose(timeout_s=5.0))  # e.g. the cycle's move, reconnecting
        await c.wait_for_line(1, held)
        first.cancel()
        with pytest.raises(asyncio.CancelledError):
            await first
        assert not robot.connected  # the half-made connection is closed, not kept as the live one

        assert await robot.read_pose(timeout_s=5.0) == POSE  # the next call connects afresh
        assert robot.connections == 2 and robot.connected
        assert robot.info is not None and robot.info.robot_type == "TEST ROBOT"
        assert c.lines[2] == ["HELLO 1", *SETTINGS, "GETC"], c.lines
    finally:
        await robot.close()
        await c.ctl.close()


async def test_a_move_cancelled_while_reconnecting_then_repeated_sets_its_speed_on_the_new_connection() -> None:
    """The verbs cache the speed they last set; the new connection gets the cached one, the move its own."""
    c = _Controller("HELLO")
    port = await c.ctl.start()
    robot = _robot(port)
    request = MotionRequest(POSE, speed_mm_s=60.0)
    try:
        first = asyncio.create_task(robot.move(request, timeout_s=5.0))
        await c.wait_for_line(1, "HELLO 1")
        first.cancel()
        with pytest.raises(asyncio.CancelledError):
            await first
        assert await robot.move(request, timeout_s=5.0) == POSE
        assert c.lines[2] == ["HELLO 1", *SETTINGS, "SPEED 60.000 30.000", "POS 1.000 2.000 3.000",
                              "ORI 1.0000000 0.0000000 0.0000000 0.0000000", "MOVEL", "GETC"], c.lines  # fmt: skip
    finally:
        await robot.close()
        await c.ctl.close()


async def test_close_during_the_handshake_fails_the_connecting_call_and_leaves_nothing_open() -> None:
    c = _Controller("HELLO")
    port = await c.ctl.start()
    robot = _robot(port)
    try:
        first = asyncio.create_task(robot.read_pose(timeout_s=5.0))
        await c.wait_for_line(1, "HELLO 1")
        await robot.close()
        with pytest.raises(DeviceDisconnected, match="closed during the handshake"):
            await asyncio.wait_for(first, 2.0)
        assert not robot.connected
        with pytest.raises(DeviceDisconnected, match="closed"):
            await robot.read_pose(timeout_s=1.0)
    finally:
        await robot.close()
        await c.ctl.close()
