"""Shared helpers for the ABB driver tests (loopback only, ephemeral ports)."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
from collections.abc import AsyncIterator, Callable

from abb_robot import AbbRobot, AbbRobotSettings
from abb_robot.fake import EgmDynamics, FakeController, FakeControllerConfig
from shared_support import free_port

LOOPBACK = "127.0.0.1"


def free_udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


def start_fake(**overrides: object) -> FakeController:
    """A fake controller on its own loop thread; EGM goes to ``egm_sensor_port`` if given."""
    cfg = FakeControllerConfig(**overrides)  # type: ignore[arg-type]
    fake = FakeController(cfg)
    fake.start_in_thread()
    return fake


def settings_for(fake: FakeController, egm_port: int | None = None, **overrides: object) -> AbbRobotSettings:
    assert fake.rapid_port is not None
    base: dict[str, object] = dict(
        host=LOOPBACK,
        rapid_port=fake.rapid_port,
        egm_port=egm_port,
        egm_bind_host=LOOPBACK,
        connect_timeout_s=2.0,
        request_timeout_s=2.0,
        heartbeat_period_s=0.3,
        heartbeat_timeout_s=0.5,
        reconnect_delay_s=0.1,
        reconnect_max_delay_s=0.5,
    )
    base.update(overrides)
    return AbbRobotSettings(**base)  # type: ignore[arg-type]


@contextlib.asynccontextmanager
async def fake_and_robot(
    *, egm: bool = False, fake_kw: dict[str, object] | None = None, robot_kw: dict[str, object] | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> AsyncIterator[tuple[FakeController, AbbRobot]]:
    """A fake controller (fast moves) and a connected client (its stream on ``clock``); both torn down afterwards."""
    egm_port = free_udp_port() if egm else None
    kw: dict[str, object] = dict(time_scale=0.05, egm=EgmDynamics(comm_timeout_s=0.5))
    if egm_port is not None:
        kw["egm_sensor_port"] = egm_port
    kw.update(fake_kw or {})
    fake = start_fake(**kw)
    robot = AbbRobot(settings_for(fake, egm_port, **(robot_kw or {})), clock=clock)
    try:
        await robot.connect(timeout_s=3.0)
        yield fake, robot
    finally:
        await robot.close()
        fake.stop_thread()


class ScriptedController:
    """A TCP server that answers lines with a script: ``respond(line) -> list of raw lines``.

    It stands in for a controller that misbehaves (garbage, silence), which the fake never does.
    """

    def __init__(self, respond: Callable[[str], list[bytes]]) -> None:
        self.respond = respond
        self.server: asyncio.base_events.Server | None = None
        self.connections = 0
        self.received: list[str] = []

    async def start(self) -> int:
        self.server = await asyncio.start_server(self._serve, LOOPBACK, 0)
        return int(self.server.sockets[0].getsockname()[1])

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        try:
            while True:
                raw = await reader.readline()
                if not raw:
                    return
                line = raw.decode().rstrip("\n")
                self.received.append(line)
                for out in self.respond(line):
                    writer.write(out)
                await writer.drain()
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            writer.close()

    async def close(self) -> None:
        if self.server is not None:
            self.server.close()


def hello_then(respond: Callable[[int, str, list[str]], list[bytes] | None]) -> Callable[[str], list[bytes]]:
    """A script that does the handshake and settings properly, then asks ``respond``."""

    def script(line: str) -> list[bytes]:
        rid_s, verb, *args = line.split(" ")
        rid = int(rid_s)
        custom = respond(rid, verb, args)
        if custom is not None:
            return custom
        if verb == "HELLO":
            return [f"{rid} OK 1 TEST_ROBOT RW_TEST\n".encode()]
        if verb in ("TOOL", "WOBJ"):
            return [f"{rid} OK {args[0]}\n".encode()]
        if verb in ("SPEED", "ZONE", "BYE"):
            return [f"{rid} OK\n".encode()]
        if verb == "PING":
            return [f"{rid} PONG\n".encode()]
        return []

    return script


@contextlib.asynccontextmanager
async def scripted_robot(
    respond: Callable[[int, str, list[str]], list[bytes] | None], *, connect: bool = True
) -> AsyncIterator[tuple[AbbRobot, ScriptedController]]:
    """A robot driver on 127.0.0.1 talking to a :class:`ScriptedController` that answers through
    ``hello_then(respond)``; connected unless ``connect`` is False; both closed after."""
    ctl = ScriptedController(hello_then(respond))
    port = await ctl.start()
    robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=port, egm_port=None, heartbeat_period_s=5.0))
    try:
        if connect:
            await robot.connect(timeout_s=2.0)
        yield robot, ctl
    finally:
        await robot.close()
        await ctl.close()
