"""The line-protocol server of the fake controller: what ``rapid/CellctlServer.mod`` does, in asyncio.

It behaves as the RAPID module does, verb for verb and error for error:

- one client at a time (a second connection waits, unanswered, until the first one ends);
- HELLO first on every connection; staged POS/ORI are cleared by HELLO and consumed by a move;
- motions and EGM sessions run in the background: ``ACK`` at once, ``DONE`` or ``ERR`` later,
  while PING, GETC, GETJ, STATE, STOP, POS and ORI are still answered; settings, GRIP and new
  motions get ``ERR 110`` (BUSY) meanwhile;
- GRIP switches the robot's gripper output, then waits the gripper's settle time before it
  answers, reading nothing meanwhile (the module's ``WaitTime``);
- STREAM 1/0 starts or stops the EGM position stream (refused while a motion runs; moves run
  while it streams; EGM is refused with BUSY meanwhile); STOP ends it as well;
- a line longer than 80 bytes gets ``0 ERR 101`` and is dropped up to its newline;
- a client that sends nothing for ``idle_timeout_s`` is dropped; when the client goes away
  (or says BYE) during a motion or a stream, they are stopped (the module does the same: no
  motion and no stream without its client).

For tests it can also go silent (read and answer nothing) and drop its client on request.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from abb_robot import protocol as P
from abb_robot.fake.egm_robot import EgmEnd, EgmOutcome, EgmRobotSide, EgmSessionParams
from abb_robot.fake.robot import FakeRobot
from cellctl.ports import CartesianPose

if TYPE_CHECKING:
    from abb_robot.fake.controller import FakeControllerConfig

log = logging.getLogger(__name__)

_EGM_ERRORS = {
    EgmEnd.COMM_TIMEOUT: P.ErrorCode.EGM_COMM,
    EgmEnd.STOPPED: P.ErrorCode.STOPPED,
    EgmEnd.MOTORS_OFF: P.ErrorCode.EGM_STATE,
    EgmEnd.UNREACHABLE: P.ErrorCode.EGM_STATE,
}
_UNKNOWN_FRAME = {"tool": P.ErrorCode.UNKNOWN_TOOL, "wobj": P.ErrorCode.UNKNOWN_WOBJ}


@dataclass
class ServerIdentity:
    """What HELLO reports about the controller."""

    robot_type: str = "IRB 7600-325/3.1"
    rw_version: str = "fake-6.16"


@dataclass
class _Session:
    writer: asyncio.StreamWriter
    hello: bool = False
    staged_pos: tuple[float, float, float] | None = None
    staged_ori: tuple[float, float, float, float] | None = None
    tasks: set[asyncio.Task[None]] = field(default_factory=set)


class RapidLineServer:
    """Serves the cellctl line protocol for one :class:`FakeRobot` (and its EGM side)."""

    KEEP_LINES = 10_000
    """How many received lines :attr:`lines_received` keeps by default (a served cell sends ~150 a cycle)."""

    def __init__(
        self, robot: FakeRobot, egm: EgmRobotSide | None, config: FakeControllerConfig, *, keep_lines: int = KEEP_LINES
    ) -> None:
        if keep_lines < 1:
            raise ValueError(f"keep_lines must be at least 1, got {keep_lines}")
        self.robot = robot
        self.egm = egm
        self.config = config
        """The controller's configuration: ``identity``, ``idle_timeout_s`` and ``gripper_settle_s`` are read here."""
        self.silent = False
        self.keep_lines = keep_lines
        self.lines_received: list[str] = []
        """The most recent lines received, oldest first, at most ``keep_lines`` (for tests and diagnostics)."""
        self._server: asyncio.base_events.Server | None = None
        self._one_client = asyncio.Lock()
        self._current: _Session | None = None
        self._motion_task: asyncio.Task[None] | None = None
        self._stop_event: asyncio.Event | None = None

    async def start(self, host: str, port: int) -> int:
        self._server = await asyncio.start_server(self._serve, host, port, limit=4096)
        return int(self._server.sockets[0].getsockname()[1])

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
        self.drop_client()
        await self._halt_motion()
        await self._end_stream()
        if self._server is not None:
            try:
                await asyncio.wait_for(self._server.wait_closed(), 1.0)
            except asyncio.TimeoutError:
                pass

    def drop_client(self) -> None:
        """Close the current connection abruptly (as a cable pull or controller restart would)."""
        if self._current is not None:
            transport = self._current.writer.transport
            transport.abort()

    @property
    def busy(self) -> bool:
        return self._motion_task is not None and not self._motion_task.done()

    # -- connection ---------------------------------------------------------------------------

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            async with self._one_client:  # a second client waits its turn (closed if the controller stops meanwhile)
                session = _Session(writer)
                self._current = session
                try:
                    await self._session(reader, session)
                except (ConnectionError, asyncio.IncompleteReadError, OSError):
                    pass
                finally:
                    self._current = None
                    if self.busy:
                        log.info("client gone during a motion: stopping it")
                        await self._halt_motion()
                    await self._end_stream()
        finally:
            writer.close()

    async def _session(self, reader: asyncio.StreamReader, session: _Session) -> None:
        pending = b""
        discarding = False
        while True:
            try:
                chunk = await asyncio.wait_for(reader.read(256), self.config.idle_timeout_s)
            except asyncio.TimeoutError:
                log.info("client silent for %.1f s: dropping it", self.config.idle_timeout_s)
                return
            if not chunk:
                return
            if self.silent:
                continue
            pending += chunk
            while True:
                nl = pending.find(b"\n")
                if nl < 0:
                    if len(pending) > P.MAX_LINE - 1:
                        if not discarding:
                            await self._send(session, P.format_error(0, P.ErrorCode.TOO_LONG, "line over 80 chars"))
                        discarding = True
                        pending = b""
                    break
                raw, pending = pending[:nl], pending[nl + 1 :]
                if discarding:
                    discarding = False
                    continue
                if len(raw) + 1 > P.MAX_LINE:
                    await self._send(session, P.format_error(0, P.ErrorCode.TOO_LONG, "line over 80 chars"))
                    continue
                if await self._line(session, raw):
                    return

    async def _send(self, session: _Session, data: bytes) -> None:
        if self.silent:
            return
        session.writer.write(data)
        await session.writer.drain()

    # -- requests -----------------------------------------------------------------------------

    async def _line(self, s: _Session, raw: bytes) -> bool:
        """Handle one line; True when the connection is to be closed (BYE)."""
        try:
            text = P.strip_line(raw.decode("ascii"))
        except UnicodeDecodeError:
            await self._send(s, P.format_error(0, P.ErrorCode.SYNTAX, "line is not ASCII"))
            return False
        lines = self.lines_received
        lines.append(text)
        if len(lines) > self.keep_lines:  # the oldest go: a served cell's fake runs for months
            del lines[: len(lines) - self.keep_lines]
        try:
            req = P.parse_request(text)
        except P.ProtocolError as exc:
            await self._send(s, P.format_error(exc.req_id, exc.code, str(exc)))
            return False
        rid, verb, args = req.req_id, req.verb, req.args
        spec = P.VERBS[verb]
        if not s.hello and verb not in ("HELLO", "BYE"):
            await self._send(s, P.format_error(rid, P.ErrorCode.NO_HELLO, "send HELLO first"))
            return False
        if self.busy and not spec.while_moving:
            await self._send(s, P.format_error(rid, P.ErrorCode.BUSY, f"{verb} refused: a motion is running"))
            return False
        handler = getattr(self, f"_do_{verb.lower()}")
        return bool(await handler(s, rid, *args))

    async def _ok(self, s: _Session, rid: int, *fields: str) -> None:
        await self._send(s, P.format_reply(rid, P.Status.OK, *fields))

    async def _err(self, s: _Session, rid: int, code: P.ErrorCode, text: str) -> None:
        await self._send(s, P.format_error(rid, code, text))

    async def _do_hello(self, s: _Session, rid: int, version: int) -> None:
        if version != P.PROTOCOL_VERSION:
            await self._err(s, rid, P.ErrorCode.VERSION, f"version {version} not supported, server speaks {P.PROTOCOL_VERSION}")
            return
        s.hello = True
        s.staged_pos = s.staged_ori = None
        robot_type = "_".join(self.config.identity.robot_type.split(" "))[:28] or "-"
        rw = "_".join(self.config.identity.rw_version.split(" "))[:28] or "-"
        await self._ok(s, rid, str(P.PROTOCOL_VERSION), robot_type, rw)

    async def _do_ping(self, s: _Session, rid: int) -> None:
        await self._send(s, P.format_reply(rid, P.Status.PONG))

    async def _do_bye(self, s: _Session, rid: int) -> bool:
        await self._ok(s, rid)
        return True

    async def _select_frame(self, kind: str, s: _Session, rid: int, name: str) -> None:
        """TOOL and WOBJ: make the named tooldata or wobjdata the current one (not while a position stream
        runs: its feedback's frame was fixed at STREAM 1)."""
        if self.streaming:
            await self._err(s, rid, P.ErrorCode.BUSY, f"{kind.upper()} refused: a position stream runs (STREAM 0 first)")
            return
        if name not in getattr(self.robot, f"{kind}s"):
            await self._err(s, rid, _UNKNOWN_FRAME[kind], f"no {kind}data {name}")
            return
        with self.robot.lock:
            setattr(self.robot, f"{kind}_name", name)
        await self._ok(s, rid, name)

    _do_tool = functools.partialmethod(_select_frame, "tool")
    _do_wobj = functools.partialmethod(_select_frame, "wobj")

    async def _do_speed(self, s: _Session, rid: int, v_tcp: float, v_ori: float) -> None:
        if not (0 < v_tcp <= 7000 and 0 < v_ori <= 1000):
            await self._err(s, rid, P.ErrorCode.RANGE, "speed needs 0<v_tcp<=7000 mm/s, 0<v_ori<=1000 deg/s")
            return
        with self.robot.lock:
            self.robot.speed = (v_tcp, v_ori)
        await self._ok(s, rid, P.format_num(v_tcp, 1), P.format_num(v_ori, 1))

    async def _do_zone(self, s: _Session, rid: int, zone_mm: float) -> None:
        if not (0 <= zone_mm <= 2000):
            await self._err(s, rid, P.ErrorCode.RANGE, "zone needs 0<=zone_mm<=2000 (0 = fine)")
            return
        with self.robot.lock:
            self.robot.zone_mm = zone_mm
        await self._ok(s, rid, P.format_num(zone_mm, 1))

    async def _do_pos(self, s: _Session, rid: int, x: float, y: float, z: float) -> None:
        if max(abs(x), abs(y), abs(z)) > P.MAX_ABS_POSITION_MM:
            await self._err(s, rid, P.ErrorCode.RANGE, "position beyond +-99999 mm")
            return
        s.staged_pos, s.staged_ori = (x, y, z), None
        await self._ok(s, rid)

    async def _do_ori(self, s: _Session, rid: int, q1: float, q2: float, q3: float, q4: float) -> None:
        if s.staged_pos is None:
            await self._err(s, rid, P.ErrorCode.SEQUENCE, "ORI needs a POS before it")
            return
        norm = math.sqrt(q1 * q1 + q2 * q2 + q3 * q3 + q4 * q4)
        if abs(norm - 1.0) > 1e-3:
            await self._err(s, rid, P.ErrorCode.RANGE, f"quaternion norm {norm:.6f} is not 1")
            return
        s.staged_ori = (q1 / norm, q2 / norm, q3 / norm, q4 / norm)
        await self._ok(s, rid)

    async def _do_movel(self, s: _Session, rid: int) -> None:
        await self._move(s, rid, linear=True)

    async def _do_movej(self, s: _Session, rid: int) -> None:
        await self._move(s, rid, linear=False)

    async def _move(self, s: _Session, rid: int, *, linear: bool) -> None:
        if s.staged_pos is None or s.staged_ori is None:
            await self._err(s, rid, P.ErrorCode.NO_TARGET, "stage POS and ORI before a move")
            return
        target = CartesianPose(s.staged_pos, s.staged_ori)
        s.staged_pos = s.staged_ori = None
        await self._send(s, P.format_reply(rid, P.Status.ACK))
        self._start_background(s, self._run_move(s, rid, target, linear))

    def _start_background(self, s: _Session, coro: "asyncio.Future[None] | object") -> None:
        self._stop_event = asyncio.Event()
        self._motion_task = asyncio.ensure_future(coro)  # type: ignore[arg-type]

    async def _run_move(self, s: _Session, rid: int, target: CartesianPose, linear: bool) -> None:
        flange_target, refusal = self.robot.check(target)
        if refusal is not None:
            code = P.ErrorCode.REACH if refusal.kind == "reach" else P.ErrorCode.JOINT_LIMIT
            await self._reply_quietly(s, P.format_error(rid, code, refusal.reason))
            return
        if not self.robot.motors_on:
            await self._reply_quietly(s, P.format_error(rid, P.ErrorCode.MOTION, "motors are off"))
            return
        motion = self.robot.begin_motion(flange_target, linear)
        assert self._stop_event is not None
        try:
            await asyncio.wait_for(self._stop_event.wait(), motion.duration_s)
        except asyncio.TimeoutError:
            self.robot.finish_motion(motion)
            await self._reply_quietly(s, P.format_reply(rid, P.Status.DONE))
            return
        self.robot.halt()
        await self._reply_quietly(s, P.format_error(rid, P.ErrorCode.STOPPED, "motion stopped"))

    async def _reply_quietly(self, s: _Session, data: bytes) -> None:
        """A completion reply; the client may be gone by then (the motion ends all the same)."""
        try:
            await self._send(s, data)
        except (ConnectionError, OSError, RuntimeError):
            pass

    async def _do_egm(self, s: _Session, rid: int, band_mm: float, band_deg: float, cond_s: float) -> None:
        if self.streaming:  # one EGM user at a time on the UdpUc device
            await self._err(s, rid, P.ErrorCode.BUSY, "EGM refused: a position stream runs")
            return
        if not (band_mm > 0 and band_deg > 0 and 0 < cond_s <= 3600):
            await self._err(s, rid, P.ErrorCode.RANGE, "EGM needs band_mm>0, band_deg>0, 0<cond_s<=3600")
            return
        await self._send(s, P.format_reply(rid, P.Status.ACK))
        if self.egm is None:  # the module finds this out in the motion task, after its ACK
            await self._send(s, P.format_error(rid, P.ErrorCode.EGM_SETUP, "EGM setup failed: no UdpUc device"))
            return
        self._start_background(s, self._run_egm(s, rid, EgmSessionParams(band_mm, band_deg, cond_s)))

    async def _run_egm(self, s: _Session, rid: int, params: EgmSessionParams) -> None:
        assert self.egm is not None and self._stop_event is not None
        loop = asyncio.get_running_loop()
        done: asyncio.Future[EgmOutcome] = loop.create_future()

        def on_end(outcome: EgmOutcome) -> None:
            loop.call_soon_threadsafe(lambda: done.done() or done.set_result(outcome))

        self.egm.begin(params, on_end)
        stop_wait = asyncio.ensure_future(self._stop_event.wait())
        try:
            await asyncio.wait({done, stop_wait}, return_when=asyncio.FIRST_COMPLETED)
            if not done.done():
                self.egm.request_stop()
            outcome = await done
        finally:
            stop_wait.cancel()
        if outcome.end is EgmEnd.CONVERGED:
            await self._reply_quietly(s, P.format_reply(rid, P.Status.DONE))
        else:
            await self._reply_quietly(s, P.format_error(rid, _EGM_ERRORS[outcome.end], outcome.detail))

    async def _do_stop(self, s: _Session, rid: int) -> None:
        was = self.busy
        if was and self._stop_event is not None:
            self._stop_event.set()
        await self._end_stream()
        await self._ok(s, rid, "1" if was else "0")

    # -- position stream ------------------------------------------------------------------------

    @property
    def streaming(self) -> bool:
        """The EGM position stream runs (as far as the RAPID side knows)."""
        return self.egm is not None and self.egm.stream.running

    async def _do_stream(self, s: _Session, rid: int, on: int) -> None:
        # _line has refused STREAM while a motion runs (BUSY), as the module's HandleLine does.
        if on not in P.STREAM_VALUES:
            await self._err(s, rid, P.ErrorCode.RANGE, "STREAM needs 1 (start) or 0 (stop)")
            return
        if on == 1:
            if self.egm is None:  # EGMSetupUC fails without the UdpUc device
                await self._err(s, rid, P.ErrorCode.EGM_SETUP, "EGM stream setup failed: no UdpUc device")
                return
            await asyncio.to_thread(self.egm.start_stream)
        else:
            await self._end_stream()
        await self._ok(s, rid, str(on))

    async def _end_stream(self) -> None:
        """EGMStreamStop: returns once the last datagram has left."""
        if self.streaming:
            assert self.egm is not None
            await asyncio.to_thread(self.egm.stream.stop)

    async def _halt_motion(self) -> None:
        if self._motion_task is None or self._motion_task.done():
            return
        if self._stop_event is not None:
            self._stop_event.set()
        try:
            await asyncio.wait_for(asyncio.shield(self._motion_task), 3.0)
        except (asyncio.TimeoutError, Exception):  # noqa: BLE001 - shutting down whatever it was
            self._motion_task.cancel()

    async def _do_getc(self, s: _Session, rid: int) -> None:
        tcp = self.robot.tcp()
        await self._send(s, P.format_reply(rid, P.Status.DATA, "POS", *P.format_position_fields(tcp.position_mm)))
        await self._ok(s, rid, "ORI", *P.format_quaternion_fields(tcp.quaternion_wxyz))

    async def _do_getj(self, s: _Session, rid: int) -> None:
        try:
            joints = self.robot.joints()
        except ValueError as exc:
            await self._err(s, rid, P.ErrorCode.INTERNAL, f"joints unavailable: {exc}")
            return
        await self._ok(s, rid, *(P.format_num(math.degrees(j), P.JOINT_DECIMALS) for j in joints))

    async def _do_state(self, s: _Session, rid: int) -> None:
        await self._ok(s, rid, "1" if self.robot.motors_on else "0", "1" if self.busy else "0")

    async def _do_grip(self, s: _Session, rid: int, hold: int) -> None:
        # _line has refused GRIP while a motion runs (BUSY), as the module's HandleLine does.
        if hold not in P.GRIP_VALUES:
            await self._err(s, rid, P.ErrorCode.RANGE, "GRIP needs 0 (release) or 1 (hold)")
            return
        try:
            self.robot.set_gripper(hold == 1)
        except Exception as exc:  # noqa: BLE001 - the physics failed: answered as the module's I/O error
            log.warning("gripper physics failed: %s", exc)
            await self._err(s, rid, P.ErrorCode.GRIPPER, f"gripper output error {type(exc).__name__}")
            return
        settle_s = self.config.gripper_settle_s * self.robot.time_scale
        if settle_s > 0:
            await asyncio.sleep(settle_s)
        await self._ok(s, rid, str(hold))
