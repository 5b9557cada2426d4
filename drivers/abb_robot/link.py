"""The link to the RAPID server module: connection, framing, request multiplexing, heartbeat.

:class:`RapidLink` keeps one TCP connection at a time. One reader task routes reply lines to
their requests by id, so queries, PING and STOP go on while a motion runs. Every request has a
deadline that covers everything it does, reconnecting included; as the heartbeat stands back while
an answer is awaited, a verb answered at once waits ``request_timeout_s`` at most for it, however
long the call (GRIP, STREAM, PING and a motion's DONE keep the call's deadline). The heartbeat
(:mod:`abb_robot.heartbeat`) starts with the first connection, whoever makes it: it pings when the
link has been quiet for a period, drops the link when no PONG comes back, and reconnects in the
background with growing delays. After every (re)connection the link says HELLO, checks the
protocol version and calls its ``on_connect`` hook (the robot verbs send their tool, work object,
speed and zone again there). TCP keepalive is on as well, so a link through a dead switch does
not linger.

Replies become typed errors here: a refused target is :class:`~cellctl.ports.UnreachableTarget`;
a motion that ends early (STOP, fault, EGM timeout, lost link) is
:class:`~cellctl.ports.MotionInterrupted`; other refusals are :class:`~cellctl.ports.DeviceRejected`
with the controller's code; a silent controller gives :class:`~cellctl.ports.DeviceTimeout`;
garbage on the link gives :class:`~cellctl.ports.DeviceProtocolError` and a reconnection.
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
import math
import socket
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from abb_robot import protocol as P
from abb_robot.heartbeat import Heartbeat
from abb_robot.settings import AbbRobotSettings
from cellctl.ports import (
    DeviceDisconnected,
    DeviceError,
    DeviceProtocolError,
    DeviceRejected,
    DeviceTimeout,
    MotionInterrupted,
    UnreachableTarget,
)

log = logging.getLogger("abb_robot.client")  # the driver's log, as before the split into modules

_INTERRUPTING = {P.ErrorCode.STOPPED, P.ErrorCode.MOTION, P.ErrorCode.EGM_COMM, P.ErrorCode.EGM_STATE}
_UNREACHABLE = {P.ErrorCode.REACH, P.ErrorCode.JOINT_LIMIT}


@dataclass(frozen=True)
class ControllerInfo:
    """What the controller said in its HELLO answer."""

    protocol_version: int
    robot_type: str
    rw_version: str


@dataclass
class _Pending:
    """A request waiting for its answer (and, for a motion, for its DONE or ERR)."""

    verb: str
    motion: bool
    lines: list[P.Reply] = field(default_factory=list)
    answer: asyncio.Future[list[P.Reply]] = field(default_factory=lambda: asyncio.get_running_loop().create_future())
    final: asyncio.Future[P.Reply] | None = None


class _Connection:
    """One TCP connection with its reader task and the requests waiting on it."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader = reader
        self.writer = writer
        self.pending: dict[int, _Pending] = {}
        self.task: asyncio.Task[None] | None = None
        self.alive = True
        self.owner: RapidLink | None = None  # the link that opened it
        self.last_rx = time.monotonic()
        self.write_lock = asyncio.Lock()


# The connection the current task is setting up (HELLO, then the on_connect hook): its requests go on it before
# it is the link's live connection, which it only becomes once both completed. Tasks the hook starts inherit it.
_SETTING_UP: contextvars.ContextVar[_Connection | None] = contextvars.ContextVar("abb_link_setting_up", default=None)


def quiet(fut: asyncio.Future[object]) -> None:
    """Mark a future's exception as seen (nobody may be waiting on it any more)."""
    fut.add_done_callback(lambda f: f.cancelled() or f.exception())


def deadline_in(timeout_s: float) -> float:
    """The ``time.monotonic()`` deadline of a call given ``timeout_s``; ValueError for a bad one."""
    if not (timeout_s > 0 and math.isfinite(timeout_s)):
        raise ValueError(f"timeout_s must be a finite number > 0, got {timeout_s}")
    return time.monotonic() + timeout_s


class RapidLink:
    """The line-protocol link to one controller. See the module docstring.

    Args:
        settings: connection settings (host, port, timeouts, heartbeat, keepalive).
        name: the device's name in errors and logs.
        on_connect: awaited with the deadline after every successful HELLO; an error it raises
            fails the connection. The connection becomes the live one (``connected``, used by later
            calls) only once HELLO and the hook completed; a failure or cancellation in either closes it.
    """

    def __init__(
        self, settings: AbbRobotSettings, *, name: str, on_connect: Callable[[float], Awaitable[None]]
    ) -> None:
        self.settings = settings
        self.name = name
        self.info: ControllerInfo | None = None
        self.connections = 0
        self.closed = False
        self._on_connect = on_connect
        self._conn: _Connection | None = None
        self._opening: _Connection | None = None  # a connection still in its handshake (close() drops it too)
        self._connect_lock = asyncio.Lock()
        self._next_id = 0
        self._heartbeat = Heartbeat(self, settings, name)

    # ------------------------------------------------------------------------------------------
    # connection

    @property
    def connected(self) -> bool:
        """A live connection exists."""
        return self._conn is not None and self._conn.alive

    def quiet_for(self) -> float | None:
        """Seconds since the live connection last received a line (None: no live connection)."""
        conn = self._conn
        return None if conn is None or not conn.alive else time.monotonic() - conn.last_rx

    def waiting_for(self) -> str | None:
        """The verb of a request on the live connection still waiting for its answer, else None (its own deadline
        watches the controller then: GRIP reads nothing while the gripper settles). PING aside: a controller
        that reads lines answers it at once, so one waiting means silence, not busyness."""
        conn = self._conn
        pending = conn.pending.values() if conn is not None and conn.alive else ()
        return next((p.verb for p in pending if p.verb != "PING" and not p.answer.done()), None)

    async def ensure_connected(self, deadline: float) -> None:
        """Connect (and shake hands) unless a live connection exists; bounded by ``deadline``."""
        await self._ensure_connected(deadline)

    async def close(self) -> None:
        """Stop the heartbeat, say BYE and close the connection. Safe to call twice."""
        if self.closed:
            return
        self.closed = True
        await self._heartbeat.stop()
        conn = self._conn
        if conn is not None and conn.alive:
            try:
                await self.request("BYE", deadline=time.monotonic() + 0.5, reconnect=False)
            except DeviceError:
                pass
            self._drop(conn, DeviceDisconnected(self.name, "client closed the connection"))
        if self._opening is not None:
            self._drop(self._opening, DeviceDisconnected(self.name, "client closed during the handshake"))

    def _being_set_up(self) -> _Connection | None:
        """This link's connection the current task is setting up (inside :meth:`_connect_once`), else None."""
        conn = _SETTING_UP.get()
        return conn if conn is not None and conn.owner is self else None

    async def _ensure_connected(self, deadline: float) -> _Connection:
        if self.closed:
            raise DeviceDisconnected(self.name, "the robot client is closed")
        opening = self._being_set_up()
        if opening is not None:  # the on_connect hook's own requests: on the connection being set up, never a new one
            if not opening.alive:
                raise DeviceDisconnected(self.name, "the connection closed during its handshake")
            return opening
        conn = self._conn
        if conn is not None and conn.alive:
            return conn
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise DeviceTimeout(self.name, "no time left to connect")
        try:
            await asyncio.wait_for(self._connect_lock.acquire(), remaining)
        except asyncio.TimeoutError:
            raise DeviceTimeout(self.name, "timed out waiting for a reconnection in progress") from None
        try:
            conn = self._conn
            if conn is not None and conn.alive:
                return conn
            return await self._connect_once(deadline)
        finally:
            self._connect_lock.release()

    async def _connect_once(self, deadline: float) -> _Connection:
        """Open the TCP connection, start its reader, say HELLO and run ``on_connect``."""
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
        conn = _Connection(reader, writer)
        conn.owner = self
        conn.task = asyncio.create_task(self._read_loop(conn), name=f"{self.name}-reader")
        self.connections += 1
        self._opening = conn
        setting_up = _SETTING_UP.set(conn)
        try:
            hello = await self.request("HELLO", P.PROTOCOL_VERSION, deadline=deadline, reconnect=False, quick=True)
            fields = hello[-1].fields
            if len(fields) < 3 or fields[0] != str(P.PROTOCOL_VERSION):
                raise DeviceProtocolError(self.name, f"unexpected HELLO answer: {' '.join(fields)!r}")
            self.info = ControllerInfo(int(fields[0]), fields[1].replace("_", " "), fields[2].replace("_", " "))
            await self._on_connect(deadline)
            if self.closed or not conn.alive:
                raise DeviceDisconnected(self.name, "the connection closed during its handshake")
        except DeviceError as exc:
            self._drop(conn, exc)
            raise
        except BaseException as exc:  # cancelled (or a bug in the hook): never leave a half-made connection behind
            self._drop(conn, DeviceDisconnected(
                self.name, f"connection set-up interrupted ({type(exc).__name__}) before its handshake completed; "
                "the next call connects afresh"))  # fmt: skip
            raise
        finally:
            _SETTING_UP.reset(setting_up)
            self._opening = None
        self._conn = conn  # live only now: HELLO answered and the settings sent
        self._heartbeat.start()  # from the first connection on (connect() or a first request); a no-op while it runs
        log.info("%s: connected to %s:%d (%s, %s)", self.name, s.host, s.rapid_port, self.info.robot_type,
                 self.info.rw_version)
        return conn

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

    def _drop(self, conn: _Connection, error: DeviceError) -> None:
        """Take a connection down: fail what waits on it (motions as interrupted), close the socket."""
        if not conn.alive:
            return
        conn.alive = False
        if self._conn is conn:
            self._conn = None
        for p in conn.pending.values():
            if not p.answer.done():
                p.answer.set_exception(error)
                quiet(p.answer)  # type: ignore[arg-type]
            if p.final is not None and not p.final.done():
                p.final.set_exception(
                    MotionInterrupted(
                        self.name,
                        f"{p.verb}: link lost during the motion ({error.message}); the controller stops a motion "
                        "whose client is gone",
                    )
                )
                quiet(p.final)  # type: ignore[arg-type]
        conn.pending.clear()
        transport = conn.writer.transport
        if transport is not None:
            transport.abort()
        if conn.task is not None and conn.task is not asyncio.current_task():
            conn.task.cancel()
        log.log(logging.INFO if self.closed else logging.WARNING, "%s: link down: %s", self.name, error.message)

    # ------------------------------------------------------------------------------------------
    # framing and routing

    async def _read_loop(self, conn: _Connection) -> None:
        """Read reply lines until the connection goes down; garbage drops it."""
        try:
            while conn.alive:
                raw = await conn.reader.readuntil(b"\n")
                conn.last_rx = time.monotonic()
                try:
                    reply = P.parse_reply(P.decode_line(raw))
                except P.ProtocolError as exc:
                    self._drop(conn, DeviceProtocolError(self.name, f"malformed line from the controller: {exc}"))
                    return
                self._dispatch(conn, reply)
        except asyncio.IncompleteReadError:
            self._drop(conn, DeviceDisconnected(self.name, "the controller closed the connection"))
        except asyncio.LimitOverrunError:
            self._drop(conn, DeviceProtocolError(self.name, "over 1024 bytes from the controller without a newline"))
        except (ConnectionError, OSError) as exc:
            self._drop(conn, DeviceDisconnected(self.name, f"connection lost: {exc}"))

    def _dispatch(self, conn: _Connection, reply: P.Reply) -> None:
        """Route a reply line to its request by id (ACK, DATA, OK/PONG, DONE, ERR)."""
        p = conn.pending.get(reply.req_id)
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
                    conn.pending.pop(reply.req_id, None)
                    return
            elif p.final is not None and status in (P.Status.DONE, P.Status.ERR):
                p.final.set_result(reply)
                conn.pending.pop(reply.req_id, None)
                return
        else:
            if status is P.Status.DATA:
                p.lines.append(reply)
                return
            final_ok = P.Status.PONG if p.verb == "PING" else P.Status.OK
            if status in (final_ok, P.Status.ERR) and not p.answer.done():
                p.lines.append(reply)
                p.answer.set_result(p.lines)
                conn.pending.pop(reply.req_id, None)
                return
        conn.pending.pop(reply.req_id, None)
        error = DeviceProtocolError(self.name, f"unexpected {status.value} reply to {p.verb}: {' '.join(reply.fields)[:40]!r}")
        for fut in (p.answer, p.final):
            if fut is not None and not fut.done():
                fut.set_exception(error)
                quiet(fut)  # type: ignore[arg-type]

    async def probe(self, timeout_s: float) -> None:
        """The heartbeat's PING on the live connection: dropped when no PONG, nor any other line, comes within
        ``timeout_s`` (the reader gets one more turn first: a stalled event loop is no silent controller)."""
        conn = self._conn
        if conn is None or not conn.alive:
            return
        sent = time.monotonic()
        try:
            await self.request("PING", deadline=sent + timeout_s, reconnect=False)
        except DeviceTimeout:
            await asyncio.sleep(0)
            if conn.last_rx < sent:
                self._drop(conn, DeviceTimeout(self.name, f"controller silent: no PONG within {timeout_s:g} s "
                                               "(heartbeat_timeout_s); reconnecting"))
        except DeviceError:
            pass  # the link went down meanwhile; the heartbeat reconnects it

    # ------------------------------------------------------------------------------------------
    # requests

    def _new_id(self, conn: _Connection) -> int:
        for _ in range(P.MAX_REQUEST_ID):
            self._next_id = self._next_id % P.MAX_REQUEST_ID + 1
            if self._next_id not in conn.pending:
                return self._next_id
        raise DeviceRejected(self.name, "no free request id (too many requests waiting)")

    async def _send(self, verb: str, args: tuple[object, ...], deadline: float, reconnect: bool,
                    motion: bool) -> tuple[_Connection, int, _Pending]:
        """Register a request under a free id and write it; returns where its answer will arrive."""
        if reconnect:
            conn = await self._ensure_connected(deadline)
        else:
            conn = self._being_set_up() or self._conn  # HELLO and the hook go on the connection being set up
            if conn is None or not conn.alive:
                raise DeviceDisconnected(self.name, f"{verb}: not connected")
        try:
            rid = self._new_id(conn)
            data = P.format_request(rid, verb, *args)  # type: ignore[arg-type]
        except P.ProtocolError as exc:
            raise DeviceRejected(self.name, f"{verb}: {exc}", f"{int(exc.code)} {exc.code.name}") from None
        pending = _Pending(verb, motion)
        if motion:
            pending.final = asyncio.get_running_loop().create_future()
        conn.pending[rid] = pending
        remaining = deadline - time.monotonic()
        try:
            async with conn.write_lock:
                conn.writer.write(data)
                await asyncio.wait_for(conn.writer.drain(), max(remaining, 0.001))
        except asyncio.TimeoutError:
            conn.pending.pop(rid, None)
            self._drop(conn, DeviceTimeout(self.name, f"{verb}: could not send within the deadline"))
            raise DeviceTimeout(self.name, f"{verb}: could not send within the deadline") from None
        except (ConnectionError, OSError) as exc:
            self._drop(conn, DeviceDisconnected(self.name, f"connection lost: {exc}"))
            raise DeviceDisconnected(self.name, f"{verb}: connection lost while sending: {exc}") from None
        return conn, rid, pending

    async def _await_answer(
        self, conn: _Connection, rid: int, pending: _Pending, deadline: float, quick: bool
    ) -> list[P.Reply]:
        """The request's reply lines by the deadline, or within ``request_timeout_s`` for a ``quick`` one (a verb the
        controller answers at once: while it waits the heartbeat stands back); ERR raises its typed error."""
        cap = time.monotonic() + self.settings.request_timeout_s if quick else math.inf
        remaining = min(deadline, cap) - time.monotonic()
        try:
            await asyncio.wait_for(asyncio.shield(pending.answer), max(remaining, 0.0))
        except asyncio.TimeoutError:
            await asyncio.sleep(0)  # the reader's turn first: after a stalled event loop an answer may be read only now
            if not pending.answer.done():
                raise self._unanswered(conn, rid, pending, capped=cap < deadline) from None
        lines = pending.answer.result()
        last = lines[-1]
        if last.status is P.Status.ERR:
            raise self.error(pending.verb, last)
        return lines

    def _unanswered(self, conn: _Connection, rid: int, pending: _Pending, capped: bool) -> DeviceTimeout:
        """Forget a request whose answer did not come; the error names request_timeout_s when that ran out."""
        conn.pending.pop(rid, None)
        if pending.final is not None:
            pending.final.cancel()
        verb, limit = pending.verb, self.settings.request_timeout_s
        if capped:
            return DeviceTimeout(
                self.name, f"{verb}: controller silent: no answer within {limit:g} s (request_timeout_s; {verb} is "
                "answered at once): check that the controller's CellctlServer task runs and the network to it",
            )
        return DeviceTimeout(self.name, f"{verb}: no answer from the controller in time")

    async def request(
        self, verb: str, *args: object, deadline: float, reconnect: bool = True, quick: bool = False
    ) -> list[P.Reply]:
        """Send one request and return its reply lines (the last one final); ERR raises. ``quick``: a verb the
        controller answers at once (all but GRIP, STREAM, PING): its answer is awaited ``request_timeout_s`` at most."""
        conn, rid, pending = await self._send(verb, args, deadline, reconnect, motion=False)
        return await self._await_answer(conn, rid, pending, deadline, quick)

    async def start_motion(self, verb: str, *args: object, deadline: float) -> asyncio.Future[P.Reply]:
        """Send a motion request, wait for its ACK (sent at once: ``request_timeout_s`` at most); returns the future
        of its DONE/ERR, which the caller awaits under its own deadline."""
        conn, rid, pending = await self._send(verb, args, deadline, reconnect=False, motion=True)
        assert pending.final is not None
        try:
            await self._await_answer(conn, rid, pending, deadline, quick=True)
        except DeviceTimeout:
            await self.stop_quietly()
            raise
        return pending.final

    async def finish_motion(self, verb: str, final: asyncio.Future[P.Reply], deadline: float, what: str) -> None:
        """Wait for a started motion's DONE; STOP it when the deadline passes first."""
        remaining = deadline - time.monotonic()
        try:
            reply = await asyncio.wait_for(asyncio.shield(final), max(remaining, 0.0))
        except asyncio.TimeoutError:
            await self.stop_quietly()
            raise DeviceTimeout(self.name, f"{what} not done in time; a STOP was sent") from None
        if reply.status is P.Status.ERR:
            raise self.error(verb, reply)

    async def stop_quietly(self) -> None:
        """Send STOP (1 s), logging rather than raising a failure."""
        try:
            await self.request("STOP", deadline=time.monotonic() + 1.0, reconnect=False)
        except DeviceError as exc:
            log.warning("%s: STOP after a timeout failed: %s", self.name, exc)

    def error(self, verb: str, reply: P.Reply) -> DeviceError:
        """The typed error of an ERR reply."""
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
