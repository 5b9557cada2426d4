"""PING while another request waits for its answer: the RAPID server reads no line until it has answered (GRIP waits the
gripper's settle time), so a ping then says DeviceBusy and sends nothing, and the core's watchdog counts no miss; a
silent controller on a free link is still a miss."""

from __future__ import annotations

import asyncio
import time

import pytest

from _abb_testkit import LOOPBACK, ScriptedController, fake_and_robot, hello_then
from abb_robot import AbbRobot, AbbRobotSettings
from cellctl.ports import DeviceBusy, DeviceTimeout

pytestmark = pytest.mark.timeout(60)


async def test_a_ping_while_grip_settles_says_busy_and_sends_nothing() -> None:
    async with fake_and_robot(fake_kw={"time_scale": 1.0, "gripper_settle_s": 0.8}) as (fake, robot):
        grip = asyncio.ensure_future(robot.set_gripper(False, timeout_s=3.0))
        await asyncio.sleep(0.2)
        lines_before = len(fake.server.lines_received)  # type: ignore[union-attr]
        t0 = time.monotonic()
        with pytest.raises(DeviceBusy, match="busy: GRIP") as busy:
            await robot.ping(timeout_s=0.5)
        assert time.monotonic() - t0 < 0.1  # said at once, not after the ping's timeout
        assert isinstance(busy.value, DeviceTimeout)  # to a caller of the port it is a timeout like any other
        await asyncio.wait_for(grip, 3.0)
        assert not fake.gripper_hold
        await asyncio.sleep(0.1)  # a line written during the settle is read now; the heartbeat waits for 0.3 s of quiet
        assert [line for line in fake.server.lines_received[lines_before:] if line.endswith(" PING")] == []  # type: ignore[union-attr]
        assert 0.0 <= await robot.ping(timeout_s=0.5) < 0.5  # the link is free again: a real round trip
        assert robot.connections == 1


async def test_the_watchdog_counts_no_miss_while_grip_settles() -> None:
    from cellctl.cell.alarms import AlarmManager
    from cellctl.cell.watchdog import DeviceWatchdog, LinkState, WatchdogSettings

    async with fake_and_robot(fake_kw={"time_scale": 1.0, "gripper_settle_s": 1.0}) as (fake, robot):
        alarms = AlarmManager()
        seen: list[str] = []
        alarms.subscribe(lambda ev: seen.append(f"{ev.kind.name} {ev.alarm.code.name}"))
        wd = DeviceWatchdog(alarms, defaults=WatchdogSettings(period_s=0.2, timeout_s=0.15, miss_threshold=2))
        wd.add("robot", robot)
        async with wd:
            await robot.set_gripper(True, timeout_s=3.0)  # answered OK after 1 s: the robot is healthy throughout
            await asyncio.sleep(0.3)
        h = wd.health()["robot"]
        assert fake.gripper_hold
        assert seen == [] and alarms.active() == []
        assert (h.link, h.misses) == (LinkState.UP, 0) and h.pings >= 5


async def test_a_silent_controller_is_busy_only_until_the_requests_deadline() -> None:
    def respond(rid: int, verb: str, args: list[str]) -> list[bytes] | None:
        return [] if verb in ("GRIP", "PING") else None  # hung after the handshake: answers neither

    ctl = ScriptedController(hello_then(respond))
    port = await ctl.start()
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=port, egm_port=None, heartbeat_period_s=5.0))
    try:
        await robot.connect(timeout_s=1.0)
        grip = asyncio.ensure_future(robot.set_gripper(True, timeout_s=0.4))
        await asyncio.sleep(0.05)
        with pytest.raises(DeviceBusy):
            await robot.ping(timeout_s=0.2)
        with pytest.raises(DeviceTimeout, match="GRIP 1"):
            await grip
        with pytest.raises(DeviceTimeout) as silent:  # the link is free now: the ping is sent and goes unanswered
            await robot.ping(timeout_s=0.2)
        assert not isinstance(silent.value, DeviceBusy)
        assert [line.split(" ", 1)[1] for line in ctl.received if line.endswith(("GRIP 1", "PING"))] == ["GRIP 1", "PING"]
    finally:
        await robot.close()
        await ctl.close()
