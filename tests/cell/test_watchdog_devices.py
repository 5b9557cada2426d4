"""The device watchdog with small fakes that satisfy the ports (no timed assertions beyond generous bounds)."""

from __future__ import annotations

import asyncio
import gc
import time

import numpy as np
import pytest

from cellctl.cell.alarms import AlarmCode, AlarmManager
from cellctl.cell.packml import PackMLMachine
from cellctl.cell.tags import PackMLCommand, PackMLState
from cellctl.cell.watchdog import DeviceWatchdog, LinkState, WatchdogSettings, default_alarm_code
from cellctl.ports import (
    CartesianPose,
    DeviceBusy,
    DeviceTimeout,
    DistanceReading,
    Frame,
    LaserStatus,
    MotionRequest,
    RobotState,
)


class Link:
    """How a fake answers ping: up, timing out (as a driver does), hanging, or broken."""

    def __init__(self) -> None:
        self.mode = "up"
        self.calls = 0

    async def ping(self, device: str, timeout_s: float) -> float:
        self.calls += 1
        if self.mode == "up":
            await asyncio.sleep(0)
            return 0.001
        if self.mode == "timeout":
            raise DeviceTimeout(device, f"no reply within {timeout_s} s")
        if self.mode == "busy":  # another call (a long read-out) held the link for the whole timeout
            raise DeviceBusy(device, f"busy: another command did not finish within {timeout_s} s")
        if self.mode == "hang":  # a driver ignoring its own timeout
            await asyncio.sleep(60)
            return 60.0
        raise RuntimeError("driver bug")


class FakeLaser:
    def __init__(self) -> None:
        self.link = Link()

    async def read(self, *, timeout_s: float) -> DistanceReading:
        return DistanceReading(350.0, LaserStatus.OK, time.monotonic())

    async def ping(self, *, timeout_s: float) -> float:
        return await self.link.ping("laser", timeout_s)

    async def close(self) -> None:
        return None


class FakeCamera:
    def __init__(self) -> None:
        self.link = Link()

    async def grab(self, *, timeout_s: float) -> Frame:
        return Frame(np.zeros((4, 4), np.uint8), time.monotonic(), 1)

    async def ping(self, *, timeout_s: float) -> float:
        return await self.link.ping("camera", timeout_s)

    async def close(self) -> None:
        return None


class FakeRobot:
    def __init__(self) -> None:
        self.link = Link()
        self.pose = CartesianPose((1000.0, 0.0, 1200.0), (1.0, 0.0, 0.0, 0.0))

    async def move(self, request: MotionRequest, *, timeout_s: float) -> CartesianPose:
        self.pose = request.target
        return self.pose

    async def read_pose(self, *, timeout_s: float) -> CartesianPose:
        return self.pose

    async def state(self, *, timeout_s: float) -> RobotState:
        return RobotState(True, True, False)

    async def stop(self, *, timeout_s: float) -> None:
        return None

    async def set_gripper(self, hold: bool, *, timeout_s: float) -> None:
        return None

    async def ping(self, *, timeout_s: float) -> float:
        return await self.link.ping("robot", timeout_s)

    async def close(self) -> None:
        return None


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


async def executing_machine() -> PackMLMachine:
    m = PackMLMachine()
    for cmd in (PackMLCommand.CLEAR, None, PackMLCommand.RESET, None, PackMLCommand.START, None):
        if cmd is None:
            await m.state_complete()
        else:
            await m.command(cmd, actor="test", source="pytest")
    assert m.state == PackMLState.EXECUTE
    return m


def test_alarm_code_follows_the_port_and_settings_are_checked() -> None:
    assert default_alarm_code(FakeLaser()) == AlarmCode.LASER_LOST
    assert default_alarm_code(FakeCamera()) == AlarmCode.CAMERA_LOST
    assert default_alarm_code(FakeRobot()) == AlarmCode.ROBOT_LOST
    with pytest.raises(TypeError, match="alarm_code="):
        default_alarm_code(object())
    with pytest.raises(ValueError, match="timeout_s"):
        WatchdogSettings(period_s=0.1, timeout_s=0.2)
    with pytest.raises(ValueError, match="miss_threshold"):
        WatchdogSettings(miss_threshold=0)
    with pytest.raises(ValueError, match="period_s"):
        WatchdogSettings(period_s=0.0)
    wd = DeviceWatchdog(AlarmManager())
    wd.add("laser", FakeLaser())
    with pytest.raises(ValueError, match="already supervised"):
        wd.add("laser", FakeLaser())
    with pytest.raises(TypeError, match="no ping"):
        wd.add("thing", object())  # type: ignore[arg-type]


async def test_lost_sensor_holds_the_cell_and_its_return_clears_the_alarm() -> None:
    m = await executing_machine()
    am = AlarmManager(m)
    am.install()
    clock = FakeClock()
    laser, camera = FakeLaser(), FakeCamera()
    wd = DeviceWatchdog(am, defaults=WatchdogSettings(period_s=1.0, timeout_s=0.5, miss_threshold=3), clock=clock)
    wd.add("laser", laser)
    wd.add("camera", camera)
    assert wd.health()["laser"].link == LinkState.UNKNOWN and wd.health()["laser"].heartbeat_age_s is None

    h = await wd.check_once()
    assert h["laser"].link == h["camera"].link == LinkState.UP
    laser.link.mode = "timeout"
    for expected_misses in (1, 2):
        clock.t += 1.0
        h = await wd.check_once()
        assert (h["laser"].link, h["laser"].consecutive_misses) == (LinkState.DEGRADED, expected_misses)
        assert m.state == PackMLState.EXECUTE  # below the threshold: only a warning
    assert [a.code for a in am.active()] == [AlarmCode.DEVICE_SLOW]
    assert "DeviceTimeout" in (h["laser"].last_error or "")
    assert h["laser"].heartbeat_age_s == pytest.approx(2.0) and h["camera"].heartbeat_age_s == 0.0

    clock.t += 1.0
    h = await wd.check_once()
    assert h["laser"].link == LinkState.LOST and h["camera"].link == LinkState.UP
    assert m.state == PackMLState.HOLDING  # SENSOR_LOST -> Hold
    lost = am.active()
    assert [(a.code, a.source) for a in lost] == [(AlarmCode.LASER_LOST, "laser")]
    assert "3 pings missed" in lost[0].message

    clock.t += 1.0
    await wd.check_once()  # still lost: no second alarm
    assert len(am.active()) == 1 and wd.health()["laser"].misses == 4

    laser.link.mode = "up"
    clock.t += 1.0
    h = await wd.check_once()
    assert h["laser"].link == LinkState.UP and h["laser"].consecutive_misses == 0
    assert am.active() == [] and h["laser"].pings == 6 and h["laser"].misses == 4


async def _laser_watched_in_execute(
    *, miss_threshold: int
) -> tuple[PackMLMachine, AlarmManager, FakeLaser, DeviceWatchdog, FakeClock]:
    """A machine in Execute with its alarm manager, and a fake laser under a watchdog on a fake clock (1 s pings)."""
    m = await executing_machine()
    am = AlarmManager(m)
    am.install()
    clock = FakeClock()
    laser = FakeLaser()
    wd = DeviceWatchdog(am, defaults=WatchdogSettings(period_s=1.0, timeout_s=0.5, miss_threshold=miss_threshold),
                        clock=clock)  # fmt: skip
    wd.add("laser", laser)
    return m, am, laser, wd, clock


async def test_a_slow_answer_followed_by_a_good_one_clears_the_slow_alarm() -> None:
    # One missed ping warns (DEVICE_SLOW, no state change); the next answer in time ends the warning.
    m, am, laser, wd, clock = await _laser_watched_in_execute(miss_threshold=3)
    laser.link.mode = "timeout"
    h = await wd.check_once()
    assert h["laser"].link == LinkState.DEGRADED and [a.code for a in am.active()] == [AlarmCode.DEVICE_SLOW]
    laser.link.mode = "up"
    clock.t += 1.0
    h = await wd.check_once()
    assert h["laser"].link == LinkState.UP and am.active() == [] and m.state == PackMLState.EXECUTE


async def test_a_link_held_by_another_call_is_neither_an_answer_nor_a_miss() -> None:
    m, am, laser, wd, clock = await _laser_watched_in_execute(miss_threshold=2)
    await wd.check_once()
    laser.link.mode = "busy"  # a read-out longer than the threshold's pings: the cell goes on
    for _ in range(5):
        clock.t += 1.0
        h = (await wd.check_once())["laser"]
    assert (h.link, h.consecutive_misses, h.misses, h.pings) == (LinkState.UP, 0, 0, 6)
    assert h.heartbeat_age_s == pytest.approx(5.0)  # no answer came meanwhile
    assert am.active() == [] and m.state == PackMLState.EXECUTE
    laser.link.mode = "timeout"  # the link free and the device silent: misses again
    for _ in range(2):
        clock.t += 1.0
        await wd.check_once()
    assert wd.health()["laser"].link == LinkState.LOST and [a.code for a in am.active()] == [AlarmCode.LASER_LOST]


async def test_lost_robot_aborts() -> None:
    m = await executing_machine()
    am = AlarmManager(m)
    wd = DeviceWatchdog(am, defaults=WatchdogSettings(period_s=1.0, timeout_s=0.5, miss_threshold=1))
    robot = FakeRobot()
    wd.add("robot", robot)
    robot.link.mode = "broken"  # any exception from a driver counts as a miss
    h = await wd.check_once()
    assert h["robot"].link == LinkState.LOST and "RuntimeError: driver bug" in (h["robot"].last_error or "")
    assert m.state == PackMLState.ABORTING and am.stop_reason is not None
    assert am.stop_reason.code == AlarmCode.ROBOT_LOST


async def test_a_ping_that_ignores_its_timeout_is_a_miss_not_a_hang() -> None:
    am = AlarmManager()
    wd = DeviceWatchdog(am, defaults=WatchdogSettings(period_s=0.05, timeout_s=0.02, miss_threshold=1))
    cam = FakeCamera()
    cam.link.mode = "hang"
    wd.add("camera", cam)
    h = await asyncio.wait_for(wd.check_once(), timeout=5.0)
    assert h["camera"].link == LinkState.LOST and "no answer within 0.02 s" in (h["camera"].last_error or "")
    assert [a.code for a in am.active()] == [AlarmCode.CAMERA_LOST]


async def test_running_watchdog_detects_loss_and_return() -> None:
    am = AlarmManager()
    laser, robot = FakeLaser(), FakeRobot()
    settings = WatchdogSettings(period_s=0.01, timeout_s=0.005, miss_threshold=2)
    wd = DeviceWatchdog(am, defaults=settings)
    wd.add("laser", laser)
    wd.add("robot", robot, settings=WatchdogSettings(period_s=0.02, timeout_s=0.01, miss_threshold=2))

    async def until(pred: object, what: str) -> None:
        deadline = time.monotonic() + 5.0  # generous: the condition needs a few periods of 10-20 ms
        while not pred():  # type: ignore[operator]
            assert time.monotonic() < deadline, f"watchdog never reached: {what}"
            await asyncio.sleep(0.005)

    async with wd:
        await until(lambda: wd.health()["laser"].link == LinkState.UP and wd.health()["robot"].link == LinkState.UP, "up")
        laser.link.mode = "timeout"
        await until(lambda: am.find_active(AlarmCode.LASER_LOST, "laser") is not None, "laser lost")
        assert wd.health()["robot"].link == LinkState.UP
        laser.link.mode = "up"
        await until(lambda: am.find_active(AlarmCode.LASER_LOST, "laser") is None, "laser back")
        age = wd.health()["laser"].heartbeat_age_s
        assert age is not None and 0.0 <= age < 5.0
    calls = laser.link.calls
    await asyncio.sleep(0.05)
    assert laser.link.calls == calls  # stopped: no more pings
    # Both went away but stay listed until acknowledged; nothing about the robot was raised.
    assert {(a.code, a.source, a.active) for a in am.current()} == {
        (AlarmCode.DEVICE_SLOW, "laser", False), (AlarmCode.LASER_LOST, "laser", False)}  # fmt: skip


async def test_stop_ends_a_loop_whose_cancellation_the_ping_swallowed() -> None:
    # Python 3.11's asyncio.wait_for (in a driver's ping) returns the call's result when the cancel lands as the call
    # completes: the loop's task then runs on as if never cancelled. Here the first cancel is swallowed so.
    swallowed = [0]

    class SwallowingRobot(FakeRobot):
        async def ping(self, *, timeout_s: float) -> float:
            try:
                return await super().ping(timeout_s=timeout_s)
            except asyncio.CancelledError:
                swallowed[0] += 1
                if swallowed[0] > 1:  # then as asyncio would: a test that fails still ends
                    raise
                return 0.001

    robot = SwallowingRobot()
    robot.link.mode = "hang"  # every ping waits, so the cancel lands in it
    wd = DeviceWatchdog(AlarmManager(), defaults=WatchdogSettings(period_s=0.01, timeout_s=0.005, miss_threshold=2))
    wd.add("robot", robot)
    await wd.start()
    while robot.link.calls == 0:
        await asyncio.sleep(0.005)
    stopping = asyncio.ensure_future(wd.stop())
    done, _ = await asyncio.wait({stopping}, timeout=10.0)
    assert stopping in done, "stop() still waits for a loop that went on after its cancel"  # before the mend: for ever
    calls = robot.link.calls
    await asyncio.sleep(0.05)
    assert robot.link.calls == calls and swallowed[0] >= 1  # a cancel was lost, and no loop is left pinging


async def test_a_ping_failing_as_the_watchdog_stops_leaves_no_unretrieved_error() -> None:
    """A driver whose ping, cancelled, ends with its own timeout (its deadline and the cancel met): the stop raises no
    alarm and leaves no task whose error nobody read ("Task exception was never retrieved" in the service's log at the exit: the ping ran
    in a task of its own under asyncio.wait_for, which re-raised the cancel and dropped the ping's error)."""

    class TimesOutWhenCancelled(FakeRobot):
        async def ping(self, *, timeout_s: float) -> float:
            self.link.calls += 1
            try:
                await asyncio.sleep(60)
            except asyncio.CancelledError:
                raise DeviceTimeout("robot", "WOBJ: no answer from the controller in time") from None
            return 60.0

    unretrieved: list[str] = []
    loop = asyncio.get_running_loop()
    loop.set_exception_handler(lambda _loop, context: unretrieved.append(str(context.get("message"))))
    robot = TimesOutWhenCancelled()
    am = AlarmManager()
    wd = DeviceWatchdog(am, defaults=WatchdogSettings(period_s=1.0, timeout_s=0.5, miss_threshold=1))
    wd.add("robot", robot)
    try:
        await wd.start()
        while robot.link.calls == 0:
            await asyncio.sleep(0.005)
        await asyncio.wait_for(wd.stop(), 10.0)
        await asyncio.sleep(0)
        gc.collect()
        await asyncio.sleep(0)
    finally:
        loop.set_exception_handler(None)
    assert unretrieved == [], unretrieved
    # The stop's cancel is not a missed ping: no alarm (one miss would be the robot lost, an Abort), no miss counted.
    assert am.current() == [] and wd.health()["robot"].misses == 0, (am.current(), wd.health()["robot"])


async def test_a_check_that_overran_is_followed_by_one_check_not_a_burst() -> None:
    # The first ping takes five periods on the watchdog's clock (a stalled loop): the missed slots are skipped, so one
    # check follows at once and the next comes a period later, not five pings in a row to catch up.
    clock = FakeClock()
    laser = FakeLaser()
    real_ping = laser.link.ping

    async def first_one_slow(device: str, timeout_s: float) -> float:
        if laser.link.calls == 0:
            clock.t += 5.0
        return await real_ping(device, timeout_s)

    laser.link.ping = first_one_slow  # type: ignore[method-assign]
    wd = DeviceWatchdog(AlarmManager(), defaults=WatchdogSettings(period_s=1.0, timeout_s=0.5, miss_threshold=3),
                        clock=clock)  # fmt: skip
    wd.add("laser", laser)
    async with wd:
        deadline = time.monotonic() + 0.8  # the third check is due a whole period (1 s on the host's clock) later
        while laser.link.calls < 2 and time.monotonic() < deadline:
            await asyncio.sleep(0.005)
        await asyncio.sleep(0.05)
        assert laser.link.calls == 2
