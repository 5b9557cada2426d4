"""The asyncio client of the RAPID server module: :class:`AbbRobot` implements
:class:`cellctl.ports.Robot`, :class:`cellctl.ports.Identified` and, through EGM,
:class:`cellctl.ports.FineCorrection`.

Every call has a deadline (its ``timeout_s``) that covers everything it does, reconnecting
included; nothing waits without one. One reader task routes reply lines to their requests by
id, so queries, PING and STOP go on while a motion runs. A heartbeat task pings when the link
has been quiet for a period, drops the link when no PONG comes back, and reconnects in the
background with growing delays. After every (re)connection the client says HELLO, checks the
protocol version and sends its tool, work object, speed and zone again, so a controller that
restarted or lost its settings is put back into the state the cell expects. TCP keepalive is on
as well, so a link through a dead switch does not linger.

Errors are typed: a refused target is :class:`~cellctl.ports.UnreachableTarget`; a motion that
ends early (STOP, fault, EGM timeout, lost link) is :class:`~cellctl.ports.MotionInterrupted`;
other refusals are :class:`~cellctl.ports.DeviceRejected` with the controller's code; a silent
controller gives :class:`~cellctl.ports.DeviceTimeout`; garbage on the link gives
:class:`~cellctl.ports.DeviceProtocolError` and a reconnection.
"""

from __future__ import annotations

import asyncio
import logging
import math
import socket
import time
from dataclasses import dataclass, field
from typing import Literal

from abb_robot import protocol as P
from abb_robot import quat
from abb_robot.egm.peer import EgmPeer, EgmPeerSettings
from cellctl.ports import (
    CartesianPose,
    DeviceDisconnected,
    DeviceError,
    DeviceProtocolError,
    DeviceRejected,
    DeviceTimeout,
    MotionInterrupted,
    MotionRequest,
    RobotState,
    UnreachableTarget,
)

log = logging.getLogger(__name__)

_INTERRUPTING = {P.ErrorCode.STOPPED, P.ErrorCode.MOTION, P.ErrorCode.EGM_COMM, P.ErrorCode.EGM_STATE}
_UNREACHABLE = {P.ErrorCode.REACH, P.ErrorCode.JOINT_LIMIT}


@dataclass(frozen=True)
class AbbRobotSettings:
    """How to reach and drive the controller; mirrors ``[devices.robot]`` with ``kind = "abb"``.

    Attributes:
        host: controller address (its WAN/LAN port, not the service port).
        rapid_port: TCP port of the RAPID server module.
        egm_port: UDP port this PC binds for EGM (the controller's UDPUC remote port);
            None disables fine correction.
        egm_bind_host: local address the EGM port is bound on.
        connect_timeout_s: longest wait for the TCP connection itself.
        request_timeout_s: deadline of the handshake and of the settings sent after connecting.
        heartbeat_period_s: PING after this much quiet on the link.
        heartbeat_timeout_s: drop the link when a PING is not answered within this.
        reconnect_delay_s, reconnect_max_delay_s: background reconnection back-off.
        keepalive_idle_s, keepalive_interval_s, keepalive_count: TCP keepalive.
        tool, wobj: tooldata and wobjdata names on the controller (tool0/wobj0: the flange in
            the base frame, which is what :class:`cellctl.ports.Robot` speaks).
        speed_mm_s, speed_deg_s: speed sent before any move asks for its own.
        zone_mm: zone of moves; 0 is a fine point (the Robot port's moves end at fine points).
        egm_receive_timeout_s: EGM silence after which a session counts as lost.
        egm_cond_time_s: how long the pose must stay converged before the controller ends EGM.
        egm_max_correction_mm, egm_max_correction_deg: larger corrections are refused (use move()).
        egm_max_rate_hz: upper bound of the EGM reply rate.
        egm_settle_cycles: converged cycles the standalone EGM peer waits for.
        egm_rt_priority: SCHED_FIFO priority for the EGM loop (None: normal scheduling).
        egm_isolation: "process" runs the EGM loop in a child process (no interpreter lock
            shared with the cell's code), "thread" in this process.
    """

    host: str
    rapid_port: int = 30100
    egm_port: int | None = 6511
    egm_bind_host: str = "0.0.0.0"
    connect_timeout_s: float = 3.0
    request_timeout_s: float = 2.0
    heartbeat_period_s: float = 1.0
    heartbeat_timeout_s: float = 2.0
    reconnect_delay_s: float = 0.5
    reconnect_max_delay_s: float = 5.0
    keepalive_idle_s: int = 10
    keepalive_interval_s: int = 3
    keepalive_count: int = 3
    tool: str = "tool0"
    wobj: str = "wobj0"
    speed_mm_s: float = 100.0
    speed_deg_s: float = 30.0
    zone_mm: float = 0.0
    egm_receive_timeout_s: float = 0.5
    egm_cond_time_s: float = 0.1
    egm_max_correction_mm: float = 20.0
    egm_max_correction_deg: float = 2.0
    egm_max_rate_hz: float = 250.0
    egm_settle_cycles: int = 5
    egm_rt_priority: int | None = None
    egm_isolation: Literal["process", "thread"] = "process"

    def __post_init__(self) -> None:
        if not self.host:
            raise ValueError("host must name the controller")
        if not (1 <= self.rapid_port <= 65535):
            raise ValueError(f"rapid_port must be 1..65535, got {self.rapid_port}")
        if self.egm_port is not None and not (0 <= self.egm_port <= 65535):
            raise ValueError(f"egm_port must be 0..65535 or None, got {self.egm_port}")
        for name in (
            "connect_timeout_s", "request_timeout_s", "heartbeat_period_s", "heartbeat_timeout_s",
            "reconnect_delay_s", "reconnect_max_delay_s", "speed_mm_s", "speed_deg_s",
            "egm_receive_timeout_s", "egm_max_correction_mm", "egm_max_correction_deg", "egm_max_rate_hz",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value}")
        P.check_name(self.tool, "tool")
        P.check_name(self.wobj, "wobj")
        if not (0 <= self.zone_mm <= 2000):
            raise ValueError(f"zone_mm must be 0..2000 (0 = fine), got {self.zone_mm}")
        if self.egm_rt_priority is not None and not (1 <= self.egm_rt_priority <= 99):
            raise ValueError(f"egm_rt_priority must be 1..99 or None, got {self.egm_rt_priority}")
        if self.egm_settle_cycles < 1:
            raise ValueError(f"egm_settle_cycles must be >= 1, got {self.egm_settle_cycles}")
        if self.egm_isolation not in ("process", "thread"):
            raise ValueError(f"egm_isolation must be 'process' or 'thread', got {self.egm_isolation!r}")
        if not (0 < self.egm_cond_time_s <= 60):
            raise ValueError(f"egm_cond_time_s must be in (0, 60], got {self.egm_cond_time_s}")


@dataclass(frozen=True)
class ControllerInfo:
    """What the controller said in its HELLO answer."""

    protocol_version: int
    robot_type: str
    rw_version: str


@dataclass
class _Pending:
    verb: str
    motion: bool
    lines: list[P.Reply] = field(default_factory=list)
    answer: "asyncio.Future[list[P.Reply]]" = field(default_factory=lambda: asyncio.get_running_loop().create_future())
    final: "asyncio.Future[P.Reply] | None" = None


class _Link:
    """One TCP connection with its reader task and the requests waiting on it."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader = reader
        self.writer = writer
        self.pending: dict[int, _Pending] = {}
        self.task: asyncio.Task[None] | None = None
        self.alive = True
        self.last_rx = time.monotonic()
        self.write_lock = asyncio.Lock()


def _quiet(fut: "asyncio.Future[object]") -> None:
    """Mark a future's exception as seen (nobody may be waiting on it any more)."""
    fut.add_done_callback(lambda f: f.cancelled() or f.exception())


class AbbRobot:
    """An ABB robot behind ``CellctlServer.mod`` (and EGM). See the module docstring.

    Args:
        settings: connection and motion settings.
        name: the device's name in errors and logs.
    """

    def __init__(self, settings: AbbRobotSettings, *, name: str = "robot") -> None:
        self.settings = settings
        self.name = name
        self.info: ControllerInfo | None = None
        self._link: _Link | None = None
        self._connect_lock = asyncio.Lock()
        self._closed = False
        self._next_id = 0
        self._heartbeat: asyncio.Task[None] | None = None
        self._speed = (settings.speed_mm_s, settings.speed_deg_s)
        self._tool = settings.tool
        self._wobj = settings.wobj
        self._zone = settings.zone_mm
        self.connections = 0
        self._peer: EgmPeer | None = None
        if settings.egm_port is not None:
            self._peer = EgmPeer(
                EgmPeerSettings(
                    port=settings.egm_port,
                    bind_host=settings.egm_bind_host,
                    max_rate_hz=settings.egm_max_rate_hz,
                    receive_timeout_s=settings.egm_receive_timeout_s,
                    settle_cycles=settings.egm_settle_cycles,
                    rt_priority=settings.egm_rt_priority,
                    isolation=settings.egm_isolation,
                    name=f"{name} EGM",
                )
            )

    # ------------------------------------------------------------------------------------------
    # connection

    @property
    def connected(self) -> bool:
        return self._link is not None and self._link.alive

    @property
    def egm(self) -> EgmPeer | None:
        """The EGM peer (None when EGM is not configured)."""
        return self._peer

    def identity(self) -> dict[str, str]:
        """What this robot is (:class:`cellctl.ports.Identified`): the controller's address, and its
        robot type and RobotWare version from the last HELLO answer ("" before the first connection)."""
        info = self.info
        return {
            "host": self.settings.host,
            "rapid_port": str(self.settings.rapid_port),
            "robot_type": "" if info is None else info.robot_type,
            "rw_version": "" if info is None else info.rw_version,
        }

    async def connect(self, *, timeout_s: float | None = None) -> None:
        """Connect, shake hands, send the settings, start the heartbeat, and bind EGM.

        ``timeout_s`` bounds the link and the handshake; starting the EGM process gets what is
        left of it, but at least 5 s (a fresh interpreter takes about half a second).
        """
        deadline = time.monotonic() + (timeout_s if timeout_s is not None else self.settings.connect_timeout_s
                                       + self.settings.request_timeout_s)
        await self._ensure_connected(deadline)
        if self._peer is not None:
            await self._peer.start(timeout_s=max(deadline - time.monotonic(), 5.0))
        if self._heartbeat is None:
            self._heartbeat = asyncio.create_task(self._heartbeat_loop(), name=f"{self.name}-heartbeat")

    async def close(self) -> None:
        """Say BYE, close the link and the EGM port, stop the heartbeat. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._heartbeat is not None:
            self._heartbeat.cancel()
            try:
                await asyncio.wait_for(self._heartbeat, 1.0)
            except (asyncio.CancelledError, asyncio.TimeoutError, Exception):  # noqa: BLE001 - shutting down
                pass
        link = self._link
        if link is not None and link.alive:
            try:
                await self._request("BYE", deadline=time.monotonic() + 0.5, reconnect=False)
            except DeviceError:
                pass
            self._drop(link, DeviceDisconnected(self.name, "client closed the connection"))
        if self._peer is not None:
            await self._peer.close()

    async def _ensure_connected(self, deadline: float) -> _Link:
        if self._closed:
            raise DeviceDisconnected(self.name, "the robot client is closed")
        link = self._link
        if link is not None and link.alive:
            return link
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise DeviceTimeout(self.name, "no time left to connect")
        try:
            await asyncio.wait_for(self._connect_lock.acquire(), remaining)
        except asyncio.TimeoutError:
            raise DeviceTimeout(self.name, "timed out waiting for a reconnection in progress") from None
        try:
            link = self._link
            if link is not None and link.alive:
                return link
            return await self._connect_once(deadline)
        finally:
            self._connect_lock.release()

    async def _connect_once(self, deadline: float) -> _Link:
        s = self.settings
        budget = min(deadline - time.monotonic(), s.connect_timeout_s)
        if budget <= 0:
            raise DeviceTimeout(self.name, "no time left to connect")
        try:
            reader, writer = await asyncio.wait_for(
                asyncio.open_connection(s.host, s.rapid_port, limit=1024), budget
            )
        except asyncio.TimeoutError:
            raise DeviceTimeout(self.name, f"no TCP connection to {s.host}:{s.rapid_port} within {budget:.2f} s") from None
        except OSError as exc:
            raise DeviceDisconnected(
                self.name, f"cannot connect to {s.host}:{s.rapid_port}: {exc.strerror or exc}; is the RAPID server running?"
            ) from exc
        self._configure_socket(writer)
        link = _Link(reader, writer)
        link.task = asyncio.create_task(self._read_loop(link), name=f"{self.name}-reader")
        self._link = link
        self.connections += 1
        try:
            hello = await self._request("HELLO", P.PROTOCOL_VERSION, deadline=deadline, reconnect=False)
            fields = hello[-1].fields
            if len(fields) < 3 or fields[0] != str(P.PROTOCOL_VERSION):
                raise DeviceProtocolError(self.name, f"unexpected HELLO answer: {' '.join(fields)!r}")
            self.info = ControllerInfo(int(fields[0]), fields[1].replace("_", " "), fields[2].replace("_", " "))
            await self._resync(deadline)
        except DeviceError as exc:
            self._drop(link, exc)
            raise
        log.info("%s: connected to %s:%d (%s, %s)", self.name, s.host, s.rapid_port, self.info.robot_type,
                 self.info.rw_version)
        return link

    def _configure_socket(self, writer: asyncio.StreamWriter) -> None:
        sock = writer.get_extra_info("socket")
        if sock is None:
            return
        s = self.settings
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        for opt, value in (
            ("TCP_KEEPIDLE", s.keepalive_idle_s),
            ("TCP_KEEPINTVL", s.keepalive_interval_s),
            ("TCP_KEEPCNT", s.keepalive_count),
        ):
            if hasattr(socket, opt):
                sock.setsockopt(socket.IPPROTO_TCP, getattr(socket, opt), int(value))

    async def _resync(self, deadline: float) -> None:
        """Send tool, work object, speed and zone (after every connection)."""
        for verb, args in (
            ("TOOL", (self._tool,)),
            ("WOBJ", (self._wobj,)),
            ("SPEED", self._speed),
            ("ZONE", (self._zone,)),
        ):
            while True:
                try:
                    await self._request(verb, *args, deadline=deadline, reconnect=False)
                    break
                except DeviceRejected as exc:
                    # The controller may still be stopping a motion whose client went away.
                    if exc.code != f"{int(P.ErrorCode.BUSY)} BUSY" or time.monotonic() + 0.05 >= deadline:
                        raise
                    await asyncio.sleep(0.05)

    def _drop(self, link: _Link, error: DeviceError) -> None:
        """Take a link down: fail what waits on it (motions as interrupted), close the socket."""
        if not link.alive:
            return
        link.alive = False
        if self._link is link:
            self._link = None
        for p in link.pending.values():
            if not p.answer.done():
                p.answer.set_exception(error)
                _quiet(p.answer)  # type: ignore[arg-type]
            if p.final is not None and not p.final.done():
                p.final.set_exception(
                    MotionInterrupted(
                        self.name,
                        f"{p.verb}: link lost during the motion ({error.message}); the controller stops a motion "
                        "whose client is gone",
                    )
                )
                _quiet(p.final)  # type: ignore[arg-type]
        link.pending.clear()
        transport = link.writer.transport
        if transport is not None:
            transport.abort()
        if link.task is not None and link.task is not asyncio.current_task():
            link.task.cancel()
        log.log(logging.INFO if self._closed else logging.WARNING, "%s: link down: %s", self.name, error.message)

    async def _read_loop(self, link: _Link) -> None:
        try:
            while link.alive:
                raw = await link.reader.readuntil(b"\n")
                link.last_rx = time.monotonic()
                try:
                    reply = P.parse_reply(P.decode_line(raw))
                except P.ProtocolError as exc:
                    self._drop(link, DeviceProtocolError(self.name, f"malformed line from the controller: {exc}"))
                    return
                self._dispatch(link, reply)
        except asyncio.IncompleteReadError:
            self._drop(link, DeviceDisconnected(self.name, "the controller closed the connection"))
        except asyncio.LimitOverrunError:
            self._drop(link, DeviceProtocolError(self.name, "over 1024 bytes from the controller without a newline"))
        except (ConnectionError, OSError) as exc:
            self._drop(link, DeviceDisconnected(self.name, f"connection lost: {exc}"))

    def _dispatch(self, link: _Link, reply: P.Reply) -> None:
        p = link.pending.get(reply.req_id)
        if p is None:
            if reply.req_id == 0 and reply.status is P.Status.ERR:
                log.warning("%s: controller could not read a line: %s", self.name, reply.error_text)
            else:
                log.debug("%s: reply for no waiting request (late answer?): %s", self.name, reply)
            return
        status = reply.status
        if p.motion:
            if not p.answer.done():
                if status is P.Status.ACK:
                    p.answer.set_result([reply])
                    return
                if status is P.Status.ERR:
                    p.answer.set_result([reply])
                    link.pending.pop(reply.req_id, None)
                    return
            elif p.final is not None and status in (P.Status.DONE, P.Status.ERR):
                p.final.set_result(reply)
                link.pending.pop(reply.req_id, None)
                return
        else:
            if status is P.Status.DATA:
                p.lines.append(reply)
                return
            final_ok = P.Status.PONG if p.verb == "PING" else P.Status.OK
            if status in (final_ok, P.Status.ERR) and not p.answer.done():
                p.lines.append(reply)
                p.answer.set_result(p.lines)
                link.pending.pop(reply.req_id, None)
                return
        link.pending.pop(reply.req_id, None)
        error = DeviceProtocolError(self.name, f"unexpected {status.value} reply to {p.verb}: {' '.join(reply.fields)[:40]!r}")
        for fut in (p.answer, p.final):
            if fut is not None and not fut.done():
                fut.set_exception(error)
                _quiet(fut)  # type: ignore[arg-type]

    async def _heartbeat_loop(self) -> None:
        """PING a quiet link, drop it when the PONG does not come, reconnect in the background."""
        s = self.settings
        delay = s.reconnect_delay_s
        next_attempt = 0.0
        while not self._closed:
            await asyncio.sleep(min(s.heartbeat_period_s, delay) / 2)
            now = time.monotonic()
            link = self._link
            if link is None or not link.alive:
                if now < next_attempt:
                    continue
                try:
                    await self._ensure_connected(now + s.connect_timeout_s + s.request_timeout_s)
                    delay = s.reconnect_delay_s
                except DeviceError as exc:
                    log.info("%s: reconnection failed (%s); next try in %.1f s", self.name, exc.message, delay)
                    next_attempt = time.monotonic() + delay
                    delay = min(delay * 2, s.reconnect_max_delay_s)
                continue
            if now - link.last_rx < s.heartbeat_period_s:
                continue
            try:
                await self._request("PING", deadline=now + s.heartbeat_timeout_s, reconnect=False)
            except DeviceTimeout:
                self._drop(link, DeviceTimeout(self.name, f"controller silent: no PONG within {s.heartbeat_timeout_s:g} s"))
            except DeviceError:
                pass  # the link went down meanwhile; the next round reconnects

    # ------------------------------------------------------------------------------------------
    # requests

    def _new_id(self, link: _Link) -> int:
        for _ in range(P.MAX_REQUEST_ID):
            self._next_id = self._next_id % P.MAX_REQUEST_ID + 1
            if self._next_id not in link.pending:
                return self._next_id
        raise DeviceRejected(self.name, "no free request id (too many requests waiting)")

    async def _send(self, verb: str, args: tuple[object, ...], deadline: float, reconnect: bool,
                    motion: bool) -> tuple[_Link, int, _Pending]:
        if reconnect:
            link = await self._ensure_connected(deadline)
        else:
            link = self._link
            if link is None or not link.alive:
                raise DeviceDisconnected(self.name, f"{verb}: not connected")
        try:
            rid = self._new_id(link)
            data = P.format_request(rid, verb, *args)  # type: ignore[arg-type]
        except P.ProtocolError as exc:
            raise DeviceRejected(self.name, f"{verb}: {exc}", f"{int(exc.code)} {exc.code.name}") from None
        pending = _Pending(verb, motion)
        if motion:
            pending.final = asyncio.get_running_loop().create_future()
        link.pending[rid] = pending
        remaining = deadline - time.monotonic()
        try:
            async with link.write_lock:
                link.writer.write(data)
                await asyncio.wait_for(link.writer.drain(), max(remaining, 0.001))
        except asyncio.TimeoutError:
            link.pending.pop(rid, None)
            self._drop(link, DeviceTimeout(self.name, f"{verb}: could not send within the deadline"))
            raise DeviceTimeout(self.name, f"{verb}: could not send within the deadline") from None
        except (ConnectionError, OSError) as exc:
            self._drop(link, DeviceDisconnected(self.name, f"connection lost: {exc}"))
            raise DeviceDisconnected(self.name, f"{verb}: connection lost while sending: {exc}") from None
        return link, rid, pending

    async def _await_answer(self, link: _Link, rid: int, pending: _Pending, deadline: float) -> list[P.Reply]:
        remaining = deadline - time.monotonic()
        try:
            lines = await asyncio.wait_for(asyncio.shield(pending.answer), max(remaining, 0.0))
        except asyncio.TimeoutError:
            link.pending.pop(rid, None)
            if pending.final is not None:
                pending.final.cancel()
            raise DeviceTimeout(self.name, f"{pending.verb}: no answer from the controller in time") from None
        last = lines[-1]
        if last.status is P.Status.ERR:
            raise self._error(pending.verb, last)
        return lines

    async def _request(self, verb: str, *args: object, deadline: float, reconnect: bool = True) -> list[P.Reply]:
        """Send one request and return its reply lines (the last one final); ERR raises."""
        link, rid, pending = await self._send(verb, args, deadline, reconnect, motion=False)
        return await self._await_answer(link, rid, pending, deadline)

    async def _start_motion(self, verb: str, *args: object, deadline: float) -> "asyncio.Future[P.Reply]":
        """Send a motion request, wait for its ACK; returns the future of its DONE/ERR."""
        link, rid, pending = await self._send(verb, args, deadline, reconnect=False, motion=True)
        assert pending.final is not None
        try:
            await self._await_answer(link, rid, pending, deadline)
        except DeviceTimeout:
            await self._stop_quietly()
            raise
        return pending.final

    async def _finish_motion(self, verb: str, final: "asyncio.Future[P.Reply]", deadline: float, what: str) -> None:
        remaining = deadline - time.monotonic()
        try:
            reply = await asyncio.wait_for(asyncio.shield(final), max(remaining, 0.0))
        except asyncio.TimeoutError:
            await self._stop_quietly()
            raise DeviceTimeout(self.name, f"{what} not done in time; a STOP was sent") from None
        if reply.status is P.Status.ERR:
            raise self._error(verb, reply)

    async def _stop_quietly(self) -> None:
        try:
            await self._request("STOP", deadline=time.monotonic() + 1.0, reconnect=False)
        except DeviceError as exc:
            log.warning("%s: STOP after a timeout failed: %s", self.name, exc)

    def _error(self, verb: str, reply: P.Reply) -> DeviceError:
        code = reply.error_code or 0
        try:
            code_name = P.ErrorCode(code).name
        except ValueError:
            code_name = "UNKNOWN"
        text = reply.error_text
        if not text and code_name != "UNKNOWN":
            text = P.ERROR_DESCRIPTIONS[P.ErrorCode(code)]
        tag = f"{code} {code_name}"
        if code in _UNREACHABLE:
            return UnreachableTarget(self.name, f"{verb} target refused: {text}", tag)
        if code in _INTERRUPTING:
            return MotionInterrupted(self.name, f"{verb} ended early: {text} (code {tag})")
        return DeviceRejected(self.name, f"{verb} refused: {text}", tag)

    # ------------------------------------------------------------------------------------------
    # settings

    async def set_tool(self, name: str, *, timeout_s: float) -> None:
        """Select a tooldata by name (kept across reconnections)."""
        await self._request("TOOL", name, deadline=_deadline(timeout_s))
        self._tool = name

    async def set_wobj(self, name: str, *, timeout_s: float) -> None:
        """Select a wobjdata by name (kept across reconnections)."""
        await self._request("WOBJ", name, deadline=_deadline(timeout_s))
        self._wobj = name

    async def set_speed(self, speed_mm_s: float, speed_deg_s: float, *, timeout_s: float) -> None:
        await self._request("SPEED", speed_mm_s, speed_deg_s, deadline=_deadline(timeout_s))
        self._speed = (speed_mm_s, speed_deg_s)

    async def set_zone(self, zone_mm: float, *, timeout_s: float) -> None:
        """Zone of later moves; 0 is a fine point. DONE of a non-fine move comes when RAPID moves on."""
        await self._request("ZONE", zone_mm, deadline=_deadline(timeout_s))
        self._zone = zone_mm

    # ------------------------------------------------------------------------------------------
    # Robot

    async def move(self, request: MotionRequest, *, timeout_s: float) -> CartesianPose:
        deadline = _deadline(timeout_s)
        await self._ensure_connected(deadline)
        target = request.target
        q = quat.normalise(target.quaternion_wxyz)
        speed = (request.speed_mm_s, request.speed_deg_s)
        if speed != self._speed:
            await self._request("SPEED", *speed, deadline=deadline, reconnect=False)
            self._speed = speed
        await self._request("POS", *target.position_mm, deadline=deadline, reconnect=False)
        await self._request("ORI", *q, deadline=deadline, reconnect=False)
        verb = "MOVEL" if request.kind == "linear" else "MOVEJ"
        final = await self._start_motion(verb, deadline=deadline)
        await self._finish_motion(verb, final, deadline, f"{verb} to {_fmt_pose(target)}")
        return await self._read_pose(deadline, reconnect=False)

    async def read_pose(self, *, timeout_s: float) -> CartesianPose:
        return await self._read_pose(_deadline(timeout_s))

    async def _read_pose(self, deadline: float, reconnect: bool = True) -> CartesianPose:
        lines = await self._request("GETC", deadline=deadline, reconnect=reconnect)
        try:
            if len(lines) != 2 or lines[0].status is not P.Status.DATA:
                raise P.ProtocolError(f"GETC answered {len(lines)} line(s), expected DATA POS then OK ORI")
            pos = P.parse_labelled(lines[0].fields, "POS", 3)
            q = P.parse_labelled(lines[1].fields, "ORI", 4)
            return CartesianPose((pos[0], pos[1], pos[2]), quat.normalise(q))
        except (P.ProtocolError, ValueError) as exc:
            raise DeviceProtocolError(self.name, f"bad GETC answer: {exc}") from None

    async def read_joints(self, *, timeout_s: float) -> tuple[float, ...]:
        """The six joint angles in radians."""
        return await self._read_joints(_deadline(timeout_s))

    async def _read_joints(self, deadline: float) -> tuple[float, ...]:
        lines = await self._request("GETJ", deadline=deadline)
        try:
            return tuple(math.radians(v) for v in P.parse_numbers(lines[-1].fields, 6, "GETJ"))
        except P.ProtocolError as exc:
            raise DeviceProtocolError(self.name, f"bad GETJ answer: {exc}") from None

    async def state(self, *, timeout_s: float) -> RobotState:
        deadline = _deadline(timeout_s)
        lines = await self._request("STATE", deadline=deadline)
        fields = lines[-1].fields
        if len(fields) != 2 or fields[0] not in ("1", "0", "-1") or fields[1] not in ("1", "0"):
            raise DeviceProtocolError(self.name, f"bad STATE answer: {' '.join(fields)!r}")
        if fields[0] == "-1":
            log.warning("%s: the controller has no motors-on signal configured; reporting motors off", self.name)
        joints = await self._read_joints(deadline)
        return RobotState(motors_on=fields[0] == "1", program_running=True, moving=fields[1] == "1", joints_rad=joints)

    async def stop(self, *, timeout_s: float) -> None:
        await self._request("STOP", deadline=_deadline(timeout_s))

    async def ping(self, *, timeout_s: float) -> float:
        t0 = time.monotonic()
        await self._request("PING", deadline=_deadline(timeout_s))
        return time.monotonic() - t0

    # ------------------------------------------------------------------------------------------
    # FineCorrection (EGM)

    async def start_egm_session(
        self, *, band_mm: float, band_deg: float, cond_s: float, timeout_s: float
    ) -> "asyncio.Future[None]":
        """Start an EGM pose session (``EGM`` request) and return once it is acknowledged.

        The returned future resolves when the controller ends the session as converged, or
        raises the typed error (ERR 140 after :meth:`stop`, ERR 150 after a communication
        timeout). The caller streams references through :attr:`egm` meanwhile.
        """
        if self._peer is None:
            raise DeviceRejected(self.name, "EGM needs egm_port in the robot's settings")
        deadline = _deadline(timeout_s)
        await self._ensure_connected(deadline)
        await self._peer.start(timeout_s=max(deadline - time.monotonic(), 0.001))
        final = await self._start_motion("EGM", band_mm, band_deg, cond_s, deadline=deadline)
        loop = asyncio.get_running_loop()
        outcome: asyncio.Future[None] = loop.create_future()

        def settle(f: "asyncio.Future[P.Reply]") -> None:
            if outcome.done():
                return
            if f.cancelled():
                outcome.cancel()
            elif f.exception() is not None:
                outcome.set_exception(f.exception())  # type: ignore[arg-type]
            elif f.result().status is P.Status.ERR:
                outcome.set_exception(self._error("EGM", f.result()))
            else:
                outcome.set_result(None)

        final.add_done_callback(settle)
        _quiet(outcome)  # type: ignore[arg-type]
        return outcome

    async def correct_to(
        self, target: CartesianPose, *, tolerance_mm: float, tolerance_rad: float, timeout_s: float
    ) -> CartesianPose:
        """Fine-correct to ``target`` with EGM and return the reported pose once it converged.

        Starts an EGM pose session on the controller (``EGM`` request; EGMRunPose), streams
        ``target`` from the EGM peer, and returns when the controller ends the session as
        converged (every axis within ``tolerance / sqrt(3)`` for ``egm_cond_time_s``, which
        puts the pose within the tolerances). Corrections larger than
        ``egm_max_correction_mm``/``_deg`` are refused before anything moves.
        """
        if self._peer is None:
            raise DeviceRejected(self.name, "fine correction needs EGM: set egm_port in the robot's settings")
        if not (tolerance_mm > 0 and math.isfinite(tolerance_mm)):
            raise ValueError(f"tolerance_mm must be > 0, got {tolerance_mm}")
        if not (tolerance_rad > 0 and math.isfinite(tolerance_rad)):
            raise ValueError(f"tolerance_rad must be > 0, got {tolerance_rad}")
        s = self.settings
        deadline = _deadline(timeout_s)
        await self._ensure_connected(deadline)
        await self._peer.start(timeout_s=max(deadline - time.monotonic(), 0.001))
        current = await self._read_pose(deadline, reconnect=False)
        dist = math.dist(current.position_mm, target.position_mm)
        angle = math.degrees(quat.angle_between(current.quaternion_wxyz, target.quaternion_wxyz))
        if dist > s.egm_max_correction_mm or angle > s.egm_max_correction_deg:
            raise DeviceRejected(
                self.name,
                f"EGM correction of {dist:.2f} mm / {angle:.3f} deg exceeds egm_max_correction_mm="
                f"{s.egm_max_correction_mm:g} / egm_max_correction_deg={s.egm_max_correction_deg:g}; use move()",
                "LIMIT",
            )
        peer = self._peer
        session_before = peer.snapshot().session
        generation = peer.set_reference(target, tolerance_mm=tolerance_mm, tolerance_rad=tolerance_rad)
        band_mm = tolerance_mm / math.sqrt(3.0)
        band_deg = math.degrees(tolerance_rad) / math.sqrt(3.0)
        try:
            final = await self._start_motion("EGM", band_mm, band_deg, s.egm_cond_time_s, deadline=deadline)
            t_ack = time.monotonic()
            while not final.done():
                snap = peer.snapshot()
                now = time.monotonic()
                if snap.session > session_before and snap.received_at is not None:
                    if snap.fault is not None:
                        await self._stop_quietly()
                        raise MotionInterrupted(self.name, f"EGM correction stopped: {snap.fault}")
                elif now - t_ack > s.egm_receive_timeout_s:
                    await self._stop_quietly()
                    raise DeviceTimeout(
                        self.name,
                        f"no EGM data on UDP port {peer.port} within {s.egm_receive_timeout_s:g} s of the session start: "
                        "check the controller's UDPUC remote address and port and the PC firewall",
                    )
                if now >= deadline:
                    err = snap.position_error_mm
                    await self._stop_quietly()
                    detail = "" if err is None else f"; last error {err:.3f} mm"
                    raise DeviceTimeout(self.name, f"EGM correction did not converge within {timeout_s:g} s{detail}")
                await asyncio.wait({final}, timeout=0.004)
            reply = final.result()
            if reply.status is P.Status.ERR:
                raise self._error("EGM", reply)
            snap = peer.snapshot()
            if snap.feedback is None or snap.session <= session_before or snap.reference_generation != generation:
                raise DeviceProtocolError(self.name, "EGM session reported done without any EGM data")
            fb = snap.feedback
            d = math.dist(fb.position_mm, target.position_mm)
            a = quat.angle_between(fb.quaternion_wxyz, target.quaternion_wxyz)
            if d > tolerance_mm or a > tolerance_rad:
                raise MotionInterrupted(
                    self.name,
                    f"EGM session ended as converged but the reported pose is {d:.3f} mm / {math.degrees(a):.3f} deg "
                    "from the target",
                )
            return fb
        finally:
            peer.clear_reference()


def _deadline(timeout_s: float) -> float:
    if not (timeout_s > 0 and math.isfinite(timeout_s)):
        raise ValueError(f"timeout_s must be a finite number > 0, got {timeout_s}")
    return time.monotonic() + timeout_s


def _fmt_pose(p: CartesianPose) -> str:
    x, y, z = p.position_mm
    return f"({x:.1f}, {y:.1f}, {z:.1f}) mm"
