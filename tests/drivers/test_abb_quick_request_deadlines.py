"""A controller that goes silent while a quick request of a long call waits for its answer.

The RAPID server answers HELLO, the settings, POS, ORI, the queries and a motion's ACK at once; only a motion's
DONE (and GRIP's settle) take long. While a request waits for its answer the heartbeat stands back and ``ping()``
says busy, so each quick request must give up after ``request_timeout_s`` rather than after the whole call's
timeout (a move's 60 s in the cell). The silence is made by a TCP proxy on loopback that passes the request to
the protocol fake and from then on drops every byte both ways, keeping the sockets open (a hung controller, or a
RAPID task stopped from the FlexPendant: its TCP stack stays up). Judged by the clock, the fake's record of the
lines it read and the pose it reports.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator

import numpy as np
import pytest

from _abb_testkit import LOOPBACK, ScriptedController, free_udp_port, hello_then, settings_for, start_fake
from abb_robot import AbbRobot, AbbRobotSettings
from abb_robot.fake import DEFAULT_HOME, FakeController
from cellctl.ports import CartesianPose, DeviceTimeout, MotionRequest

pytestmark = pytest.mark.timeout(90)

REQUEST_S = 1.0  # request_timeout_s of these tests
CALL_S = 30.0  # the call's own timeout: far longer than any bound asserted here
STOP_S = 1.0  # the STOP a motion whose ACK did not come is followed by (link.stop_quietly)
SLACK_S = 1.0  # scheduling on a loaded machine


def _target(dx: float = 0.0, dz: float = 0.0) -> CartesianPose:
    x, y, z = DEFAULT_HOME.position_mm
    return CartesianPose((x + dx, y, z + dz), DEFAULT_HOME.quaternion_wxyz)


class SilencingProxy:
    """Loopback TCP proxy in front of the fake's RAPID port; :meth:`silence_after` arms it on a verb."""

    def __init__(self, upstream_port: int) -> None:
        self.upstream_port = upstream_port
        self.armed: str | None = None
        self.silent = False
        self.silent_since: float | None = None
        self._server: asyncio.base_events.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._served: set[tuple[asyncio.Task[None], asyncio.StreamWriter]] = set()

    async def start(self) -> int:
        self._server = await asyncio.start_server(self._serve, LOOPBACK, 0)
        return int(self._server.sockets[0].getsockname()[1])

    def silence_after(self, verb: str) -> None:
        """The next request with this verb reaches the controller; then nothing more passes, either way."""
        self.armed = verb

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._served.add((asyncio.current_task(), writer))  # type: ignore[arg-type]
        if self.silent:  # a reconnection to the hung controller: accepted, never answered
            await self._drain(reader)
            return
        up_reader, up_writer = await asyncio.open_connection(LOOPBACK, self.upstream_port)
        down = asyncio.ensure_future(self._down(up_reader, writer))
        self._tasks.add(down)
        try:
            while line := await reader.readline():
                if self.silent:
                    continue
                up_writer.write(line)
                await up_writer.drain()
                fields = line.decode().split()
                if self.armed is not None and len(fields) > 1 and fields[1] == self.armed:
                    self.silent, self.silent_since = True, time.monotonic()
        except ConnectionError:
            pass
        finally:
            down.cancel()
            up_writer.close()

    async def _down(self, up_reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        with contextlib.suppress(ConnectionError):
            while chunk := await up_reader.read(256):
                if not self.silent:
                    writer.write(chunk)
                    await writer.drain()
            while True:  # the controller closed: a hung network does not pass that on either
                await asyncio.sleep(3600)

    @staticmethod
    async def _drain(reader: asyncio.StreamReader) -> None:
        with contextlib.suppress(ConnectionError):
            while await reader.read(256):
                pass

    async def close(self) -> None:
        """Cut every connection; each handler then ends by itself (a cancelled one would be logged as an error)."""
        if self._server is not None:
            self._server.close()
        for _task, writer in self._served:
            writer.transport.abort()
        for t in self._tasks:
            t.cancel()
        pending = [t for t, _w in self._served] + list(self._tasks)
        if pending:
            await asyncio.wait(pending, timeout=2.0)


@contextlib.asynccontextmanager
async def robot_behind_proxy(time_scale: float = 0.05) -> AsyncIterator[tuple[FakeController, SilencingProxy, AbbRobot]]:
    """The fake controller, the proxy in front of it, and a connected driver (request_timeout_s = REQUEST_S)."""
    fake = start_fake(time_scale=time_scale)
    proxy = SilencingProxy(fake.rapid_port)  # type: ignore[arg-type]
    port = await proxy.start()
    robot = AbbRobot(settings_for(fake, rapid_port=port, request_timeout_s=REQUEST_S))
    try:
        await robot.connect(timeout_s=3.0)
        yield fake, proxy, robot
    finally:
        await robot.close()
        await proxy.close()
        fake.stop_thread()


async def _link_dropped_within(robot: AbbRobot, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if not robot.connected:
            return True
        await asyncio.sleep(0.02)
    return False


@pytest.mark.parametrize("verb", ["SPEED", "POS", "ORI", "MOVEL", "GETC"])
async def test_a_controller_silent_after_a_quick_request_of_a_move_fails_it_within_request_timeout(verb: str) -> None:
    async with robot_behind_proxy() as (fake, proxy, robot):
        reached = await robot.move(MotionRequest(_target(dx=20.0)), timeout_s=CALL_S)  # the proxy passes a normal move
        assert np.allclose(reached.position_mm, _target(dx=20.0).position_mm, atol=0.2)
        proxy.silence_after(verb)
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout) as err:
            # SPEED is sent only for a speed other than the last one
            await asyncio.wait_for(robot.move(MotionRequest(_target(dx=40.0), speed_mm_s=400.0), timeout_s=CALL_S),
                                   REQUEST_S + STOP_S + 5 * SLACK_S)  # fmt: skip
        failed_after = time.monotonic() - t0
        assert type(err.value) is DeviceTimeout and proxy.silent_since is not None, err.value  # the driver's, not wait_for's
        assert failed_after < REQUEST_S + STOP_S + SLACK_S, f"{verb}: move failed only after {failed_after:.1f} s"
        assert time.monotonic() - proxy.silent_since >= REQUEST_S - 0.05  # it gave the controller its request_timeout_s
        assert err.value.message.startswith(f"{verb}: controller silent: no answer within 1 s (request_timeout_s"), err.value
        assert "CellctlServer" in err.value.message
        assert fake.server.lines_received[-1].split(" ", 1)[1].startswith(verb)  # type: ignore[union-attr]  # it went out
        # the link is free again, so the heartbeat probes it and drops the silent controller
        assert await _link_dropped_within(robot, 0.3 + 0.5 + 2 * SLACK_S)


async def test_the_watchdog_sees_a_controller_gone_silent_during_a_move_request_within_seconds() -> None:
    from cellctl.cell.alarms import AlarmManager
    from cellctl.cell.watchdog import DeviceWatchdog, WatchdogSettings
    from cellctl.domain import AlarmCode

    async with robot_behind_proxy() as (_fake, proxy, robot):
        alarms = AlarmManager()
        lost_at: list[float] = []
        alarms.subscribe(lambda ev: ev.alarm.code == AlarmCode.ROBOT_LOST and lost_at.append(time.monotonic()))
        wd = DeviceWatchdog(alarms, defaults=WatchdogSettings(period_s=0.5, timeout_s=0.4, miss_threshold=3))
        wd.add("robot", robot)
        async with wd:
            proxy.silence_after("POS")
            t0 = time.monotonic()
            move = asyncio.ensure_future(robot.move(MotionRequest(_target(dx=30.0)), timeout_s=CALL_S))
            try:
                end = t0 + REQUEST_S + 3 * 0.5 + 3 * SLACK_S  # POS's request_timeout_s, then 3 missed pings
                while not lost_at and time.monotonic() < end:
                    await asyncio.sleep(0.05)
                assert lost_at, f"no ROBOT_LOST within {end - t0:.1f} s of the controller going silent during POS"
                assert alarms.find_active(AlarmCode.ROBOT_LOST, "robot") is not None
                assert move.done() and isinstance(move.exception(), DeviceTimeout), "the move still waits for POS"
                assert str(move.exception()).startswith("robot: POS: controller silent"), move.exception()
            finally:
                move.cancel()
                with contextlib.suppress(BaseException):
                    await move


async def test_a_long_move_is_not_cut_short_and_the_heartbeat_pings_during_it() -> None:
    async with robot_behind_proxy(time_scale=1.0) as (fake, _proxy, robot):
        before = len(fake.server.lines_received)  # type: ignore[union-attr]
        t0 = time.monotonic()
        reached = await robot.move(MotionRequest(_target(dx=150.0), speed_mm_s=40.0), timeout_s=CALL_S)
        took = time.monotonic() - t0
        assert took > 3 * REQUEST_S, f"the move took {took:.1f} s: not the long move this test needs"
        assert np.allclose(reached.position_mm, _target(dx=150.0).position_mm, atol=0.2)
        assert fake.robot.flange().position_mm == pytest.approx(reached.position_mm, abs=1e-3)
        during = [line.split(" ", 1)[1] for line in fake.server.lines_received[before:]]  # type: ignore[union-attr]
        assert during[during.index("MOVEL") + 1:].count("PING") >= 2, during  # the heartbeat probed while it moved
        assert robot.connections == 1


async def test_a_controller_silent_after_hello_fails_the_connecting_move_within_seconds() -> None:
    """The settings sent after connecting are quick requests too, when a move (re)connects under its 30 s."""
    ctl = ScriptedController(hello_then(lambda rid, verb, args: [] if verb == "WOBJ" else None))
    port = await ctl.start()
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=port, egm_port=None, request_timeout_s=REQUEST_S))
    try:
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match=r"^robot: WOBJ: controller silent: no answer within 1 s \(request_timeout_s"):
            await asyncio.wait_for(robot.move(MotionRequest(_target(dx=10.0)), timeout_s=CALL_S), 8.0)
        assert time.monotonic() - t0 < REQUEST_S + SLACK_S
        assert [line.split(" ", 1)[1] for line in ctl.received] == ["HELLO 1", "TOOL tool0", "WOBJ wobj0"]
        assert not robot.connected
    finally:
        await robot.close()
        await ctl.close()


async def test_an_egm_session_whose_ack_never_comes_fails_within_request_timeout() -> None:
    ctl = ScriptedController(hello_then(lambda rid, verb, args: [] if verb in ("EGM", "STOP") else None))
    port = await ctl.start()
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=port, egm_port=free_udp_port(), egm_bind_host=LOOPBACK,
                                      egm_isolation="thread", request_timeout_s=REQUEST_S))  # fmt: skip
    try:
        await robot.connect(timeout_s=3.0)
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match=r"^robot: EGM: controller silent: no answer within 1 s"):
            await asyncio.wait_for(robot.start_egm_session(band_mm=0.1, band_deg=0.1, cond_s=0.1, timeout_s=CALL_S), 8.0)
        assert time.monotonic() - t0 < REQUEST_S + STOP_S + SLACK_S
        assert [line.split(" ", 1)[1].split(" ")[0] for line in ctl.received][-2:] == ["EGM", "STOP"]  # stopped after
    finally:
        await robot.close()
        await ctl.close()
