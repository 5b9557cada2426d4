"""The ABB link's heartbeat as the service uses the driver: never ``connect()``, the first request connects.

The heartbeat starts with the first connection, whoever made it, and not before (a service started with the
controller off does not spin); it drops a half-open link (controller gone without a reset) within about
``heartbeat_period_s + heartbeat_timeout_s``, so the next request reaches the controller once it is back; and
it leaves a link busy with a long GRIP settle or a move alone. Judged by the protocol fake's own record of
the lines it read and the poses it reports, on loopback.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator

import pytest

from _abb_testkit import LOOPBACK, settings_for, start_fake
from abb_robot import AbbRobot, AbbRobotSettings
from abb_robot.fake import FakeController
from abb_robot.fake.controller import DEFAULT_HOME
from shared_support import free_port
from cellctl.ports import CartesianPose, DeviceDisconnected, DeviceTimeout, MotionRequest

pytestmark = pytest.mark.timeout(60)

PERIOD_S, TIMEOUT_S = 0.3, 0.5  # settings_for's heartbeat
BACK_HOME = CartesianPose((1800.0, 100.0, 1400.0), DEFAULT_HOME.quaternion_wxyz)  # the controller that comes back


def pings(fake: FakeController, since: int = 0) -> int:
    """How many PING lines the fake has read (after its ``since``-th line)."""
    return sum(1 for line in fake.server.lines_received[since:] if line.endswith(" PING"))  # type: ignore[union-attr]


def line_count(fake: FakeController) -> int:
    return len(fake.server.lines_received)  # type: ignore[union-attr]


@contextlib.asynccontextmanager
async def service_robot(**fake_kw: object) -> AsyncIterator[tuple[FakeController, AbbRobot]]:
    """A fake controller and a driver built as the service builds it: no connect(), nothing sent yet."""
    fake = start_fake(**{"time_scale": 0.05, **fake_kw})
    robot = AbbRobot(settings_for(fake))
    try:
        yield fake, robot
    finally:
        await robot.close()
        fake.stop_thread()


def freeze(fake: FakeController) -> None:
    """The controller goes away without a reset (cable pulled, powered off): it stops reading and answering, its
    socket stays open (no FIN, no RST), and it stops listening so a controller can come back on its port."""
    server = fake.server
    assert server is not None

    def apply() -> None:
        server.silent = True
        server._current.writer.transport.pause_reading()  # type: ignore[union-attr]  # noqa: SLF001
        server._server.close()  # type: ignore[union-attr]  # noqa: SLF001 - the listener only; the client's socket stays

    fake.call(apply)


async def test_the_first_request_starts_the_heartbeat() -> None:
    async with service_robot() as (fake, robot):
        await asyncio.sleep(2 * PERIOD_S)
        assert line_count(fake) == 0  # nothing before the first request
        pose = await robot.read_pose(timeout_s=3.0)
        assert pose.position_mm == DEFAULT_HOME.position_mm
        since = line_count(fake)
        await asyncio.sleep(4 * PERIOD_S)  # quiet: only the heartbeat talks
        assert pings(fake, since) >= 2
        assert robot.connections == 1


async def test_no_heartbeat_before_the_first_connection() -> None:
    port = free_port()
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=port, egm_port=None, heartbeat_period_s=0.2,
                                      heartbeat_timeout_s=0.2, reconnect_delay_s=0.1))
    arrivals: list[float] = []

    async def count(_r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        arrivals.append(time.monotonic())
        w.close()

    try:
        with pytest.raises(DeviceDisconnected, match="is the RAPID server running"):
            await robot.read_pose(timeout_s=1.0)  # the controller is off: the request fails, nothing stays behind
        server = await asyncio.start_server(count, LOOPBACK, port)
        try:
            await asyncio.sleep(1.0)
        finally:
            server.close()
        assert arrivals == []  # no background reconnection spins before a first connection
    finally:
        await robot.close()


async def test_a_half_open_link_is_dropped_and_the_next_request_reaches_the_controller_back() -> None:
    async with service_robot(idle_timeout_s=60.0) as (gone, robot):
        await robot.read_pose(timeout_s=3.0)  # connected by a request, as in the service
        freeze(gone)
        t0 = time.monotonic()
        back = start_fake(rapid_port=gone.rapid_port, time_scale=0.05, home=BACK_HOME)
        try:
            while robot.connected and time.monotonic() - t0 < 5.0:
                await asyncio.sleep(0.02)
            dropped_after = time.monotonic() - t0
            assert not robot.connected
            assert dropped_after < PERIOD_S + TIMEOUT_S + 0.6
            pose = await robot.read_pose(timeout_s=3.0)
            assert pose.position_mm == pytest.approx(BACK_HOME.position_mm, abs=1e-6)  # the controller that came back
            assert back.server.lines_received[0].endswith(" HELLO 1")  # type: ignore[union-attr]  # a new handshake
            assert robot.connections == 2
        finally:
            back.stop_thread()


async def test_a_pinging_caller_does_not_hide_a_half_open_link() -> None:
    # The service's watchdog pings through the port; its PING waiting unanswered is silence, not a busy link
    # (RapidLink.waiting_for), so the heartbeat still probes and drops the link.
    async with service_robot(idle_timeout_s=60.0) as (gone, robot):
        await robot.read_pose(timeout_s=3.0)
        freeze(gone)
        t0 = time.monotonic()
        while robot.connected and time.monotonic() - t0 < 5.0:
            with contextlib.suppress(DeviceTimeout, DeviceDisconnected):
                await robot.ping(timeout_s=0.25)  # one always waiting, back to back
        assert not robot.connected
        assert time.monotonic() - t0 < PERIOD_S + TIMEOUT_S + 0.8


async def test_a_long_grip_settle_keeps_the_link() -> None:
    async with service_robot(time_scale=1.0, gripper_settle_s=1.5) as (fake, robot):
        for hold in (True, False):  # 1.5 s without a line, against PING after 0.3 s quiet and PONG within 0.5 s
            await robot.set_gripper(hold, timeout_s=4.0)
            assert fake.gripper_hold is hold
        since = line_count(fake)
        await asyncio.sleep(4 * PERIOD_S)
        assert pings(fake, since) >= 2  # the heartbeat runs: it waited for GRIP, it did not die
        assert robot.connections == 1


async def test_a_long_move_is_pinged_and_keeps_the_link() -> None:
    async with service_robot(time_scale=1.0) as (fake, robot):
        start = await robot.read_pose(timeout_s=3.0)
        target = CartesianPose((start.position_mm[0] + 150.0, *start.position_mm[1:]), start.quaternion_wxyz)
        since = line_count(fake)
        await robot.move(MotionRequest(target, speed_mm_s=100.0), timeout_s=10.0)  # 1.5 s moving
        during = fake.server.lines_received[since:]  # type: ignore[union-attr]
        moved = next(i for i, line in enumerate(during) if line.endswith(" MOVEL"))
        assert sum(1 for line in during[moved:] if line.endswith(" PING")) >= 2  # the controller answers PING while moving
        assert robot.connections == 1


async def test_a_stalled_event_loop_is_no_silent_controller() -> None:
    # The PONG arrives while the driver's own loop is blocked past heartbeat_timeout_s: the link is healthy.
    async with service_robot() as (fake, robot):
        server = fake.server
        assert server is not None
        answer_ping = server._do_ping  # noqa: SLF001

        async def ping_after_50_ms(s: object, rid: int) -> None:  # the PONG leaves while the driver's loop is blocked
            await asyncio.sleep(0.05)
            await answer_ping(s, rid)  # type: ignore[arg-type]

        fake.call(lambda: setattr(server, "_do_ping", ping_after_50_ms))
        await robot.read_pose(timeout_s=3.0)
        since = line_count(fake)
        deadline = time.monotonic() + 3.0
        while pings(fake, since) == 0:
            assert time.monotonic() < deadline, "no heartbeat PING"
            await asyncio.sleep(0.002)
        time.sleep(TIMEOUT_S + 0.3)  # the loop stalls (a blocking call somewhere in the service) with the PING out
        await asyncio.sleep(PERIOD_S)
        assert robot.connected and robot.connections == 1
