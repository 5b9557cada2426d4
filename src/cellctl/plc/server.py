"""The Modbus TCP server the line PLC talks to (pymodbus 3.16, SimDevice datastore).

The datastore holds exactly the two blocks of the register map; addresses between them do not
exist. Only the configured unit id reaches it: a request to another one gets exception 11
(gateway target device failed to respond) and a warning, never pymodbus's traceback (its
SimCore raises KeyError for an unknown id, which pymodbus logs with its traceback and answers
with exception 4). One access hook guards the direction of every write: a PLC write that
touches the cell block is refused with exception 2 and counted, and the cell's own writes
(marked with a context variable) may touch only the cell block. A scan loop reads the PLC
block, supervises the PLC heartbeat, publishes the cell's status words and heartbeat, and feeds
the handshakes; its first round runs before the listener opens, so the PLC never reads an
unfilled cell block. ``start`` raises OSError, naming the ``[plc]`` setting, when it cannot
listen (pymodbus itself only logs that and raises a RuntimeError without the cause). A client whose
address is outside ``[plc] allowed_clients`` is closed when it connects, and one without a request for
``[plc] idle_timeout_s`` too; connections are capped by the open files limit, every MBAP frame of a
receive is served in order, and function codes other than the map's get exception 1
(``cellctl.plc.client_guard``).

Use::

    server = PlcServer(config.plc, cell)      # cell implements CellFacade
    await server.start()                       # listens on config.plc.host:port (server.port)
    ...
    await server.stop()

or ``async with PlcServer(config.plc, cell) as server: ...``.
"""

from __future__ import annotations

import asyncio
import contextvars
import errno
import logging
import socket
import sys
import time
from collections.abc import Callable
from types import TracebackType

from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData, SimDevice

from cellctl.config.plc import PlcConfig
from cellctl.domain import PackMLCommand, UnitMode
from cellctl.plc.client_guard import GuardedTcpServer
from cellctl.plc.connections import policy_for
from cellctl.plc.codec import decode_block
from cellctl.plc.facade import CellFacade, CellStatus
from cellctl.plc.handshake import CycleHandshake, HandshakeTiming, LatchedRequest
from cellctl.plc.heartbeat import HeartbeatWatch, LinkEvent
from cellctl.plc.process_image import CellImage, InputFeed, PlcInputs
from cellctl.plc.register_map import CELL_BLOCK, PLC_BLOCK, UNIT_ID_EXCEPTION

log = logging.getLogger(__name__)

_CELL_WRITING: contextvars.ContextVar[bool] = contextvars.ContextVar("cellctl_plc_cell_writing", default=False)
_HOLDING_REGISTER_FCS = frozenset({3, 6, 16, 22, 23})
_FC_WRITE_MULTIPLE = 16
_FC_READ_HOLDING = 3
START_TIMEOUT_S = 5.0
"""Longest wait for the listener to come up; start() raises after it rather than hang."""


def _listen_error(host: str, port: int, exc: BaseException) -> OSError:
    """An OSError that says which ``[plc]`` setting to change, keeping the cause's errno."""
    code = getattr(exc, "errno", None)
    why = (getattr(exc, "strerror", None) or str(exc) or type(exc).__name__).rstrip(".")
    if isinstance(exc, socket.gaierror) or code == errno.EADDRNOTAVAIL:
        code, hint = errno.EADDRNOTAVAIL, f"{host!r} is not an address of this machine: set [plc] host"
    elif code == errno.EADDRINUSE:
        hint = "another program (another cellctl?) has the port: set [plc] port to a free one, or stop it"
    elif code == errno.EACCES:
        hint = f"port {port} needs privileges this process does not have: set [plc] port to 1024 or above"
    else:
        hint = "check [plc] host and [plc] port"
    return OSError(code or errno.EIO, f"the PLC interface cannot listen on {host}:{port}: {why}; {hint}")


async def _probe_listen(host: str, port: int) -> None:
    """Bind and listen on every address of ``host`` as asyncio's create_server will (SO_REUSEADDR,
    IPv6 sockets v6-only), then let go. A taken port or a foreign host raises OSError here, with
    its errno: pymodbus's listen() swallows that error (it logs it and returns False)."""
    try:
        infos = await asyncio.get_running_loop().getaddrinfo(
            host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        raise _listen_error(host, port, exc) from exc
    for family, kind, proto, _name, address in {(i[0], i[1], i[2], i[3], i[4]) for i in infos}:
        try:
            with socket.socket(family, kind, proto) as sock:
                if hasattr(socket, "SO_REUSEADDR") and sys.platform != "win32":
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if family == socket.AF_INET6 and hasattr(socket, "IPPROTO_IPV6"):
                    sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
                sock.bind(address)
                sock.listen(1)
        except OSError as exc:
            raise _listen_error(host, port, exc) from exc


class _UnitGate:
    """The server's datastore as Modbus requests reach it: only ``unit_id`` (0: every id) gets through.

    Any other unit id is answered with exception 11, nothing read or written, and a warning
    (the first time per id, then every 1000th request). pymodbus turns the returned code into
    the exception response for every function code it serves from the datastore.
    """

    def __init__(self, inner: object, unit_id: int, refuse_write: Callable[[int, int, int], ExcCodes | None]) -> None:
        self._inner = inner
        self._unit_id = unit_id
        self._refuse_write = refuse_write  # (func_code, address, count): before pymodbus checks the addresses
        self.refused: dict[int, int] = {}

    def _admit(self, device_id: int, func_code: int) -> bool:
        if self._unit_id == 0 or device_id == self._unit_id:
            return True
        n = self.refused[device_id] = self.refused.get(device_id, 0) + 1
        if n % 1000 == 1:
            log.warning("PLC request (FC%d) to unit id %d answered with exception %d: this cell answers unit "
                        "id %d only ([plc] unit_id); %d such request(s) from unit id %d so far", func_code,
                        device_id, UNIT_ID_EXCEPTION, self._unit_id, n, device_id)
        return False

    async def async_getValues(self, device_id: int, func_code: int, address: int,
                              count: int = 1) -> list[int] | list[bool] | ExcCodes:
        if not self._admit(device_id, func_code):
            return ExcCodes(UNIT_ID_EXCEPTION)
        return await self._inner.async_getValues(device_id, func_code, address, count)  # type: ignore[attr-defined,no-any-return]

    async def async_setValues(self, device_id: int, func_code: int, address: int,
                              values: list[int] | list[bool]) -> ExcCodes | None:
        if not self._admit(device_id, func_code):
            return ExcCodes(UNIT_ID_EXCEPTION)
        if (refused := self._refuse_write(func_code, address, len(values))) is not None:
            return refused  # e.g. a write from the gap into the cell block, which pymodbus refuses without the hook
        return await self._inner.async_setValues(device_id, func_code, address, values)  # type: ignore[attr-defined,no-any-return]

    def device_ids(self) -> list[int]:
        return list(self._inner.device_ids())  # type: ignore[attr-defined]


class PlcServer:
    """Modbus TCP server for the line PLC, wired to the cell through ``CellFacade``."""

    def __init__(self, config: PlcConfig, cell: CellFacade,
                 *, clock: Callable[[], float] = time.monotonic) -> None:
        if not isinstance(cell, CellFacade):
            raise TypeError(f"{type(cell).__name__} does not implement CellFacade "
                            "(status, start_cycle, result_of, command, change_mode, plc_link_lost, "
                            "plc_link_restored)")
        self._config = config
        self._cell = cell
        self._clock = clock
        self._feed = InputFeed()
        self._image = CellImage()
        self._server: GuardedTcpServer | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._wake = asyncio.Event()
        self._refused_writes = 0
        self._gate: _UnitGate | None = None
        self._fault: BaseException | None = None
        self._watch = HeartbeatWatch(config.heartbeat_timeout_s, clock())
        self._cell_heartbeat = 0
        self._next_beat_s = 0.0
        self._status_failing = False
        timing = HandshakeTiming(config.scan_period_s, config.facade_timeout_s, config.cycle_result_timeout_s)
        self._cycle = CycleHandshake(cell, self._feed, self._image, self._flush, timing, clock)
        self._command = LatchedRequest(
            name="command", feed=self._feed, image=self._image, flush=self._flush,
            request_field="cmd_change_request", value_field="cntrl_cmd", ack_field="cmd_ack",
            echo_field="cmd_ack_cmd", result_field="cmd_result", kind=PackMLCommand,
            invalid=PackMLCommand.UNDEFINED, send=cell.command, timeout_s=config.facade_timeout_s)
        self._mode = LatchedRequest(
            name="unit mode", feed=self._feed, image=self._image, flush=self._flush,
            request_field="unit_mode_change_request", value_field="unit_mode_request",
            ack_field="unit_mode_ack", echo_field="unit_mode_ack_mode", result_field="unit_mode_result",
            kind=UnitMode, invalid=UnitMode.INVALID, send=cell.change_mode,
            timeout_s=config.facade_timeout_s)

    # --- life cycle -------------------------------------------------------------------------

    async def start(self, *, watch_heartbeat: bool = True) -> None:
        """Listen on the configured address and start serving; raises OSError (within
        ``START_TIMEOUT_S``) if it cannot listen, naming the ``[plc]`` setting to change.

        ``watch_heartbeat`` False defers the PLC heartbeat's first window to :meth:`watch_heartbeat`
        (the service calls it once it is up, so its own start-up does not count against the PLC)."""
        if self._server is not None:
            raise RuntimeError("the PLC server is already running")
        cfg = self._config
        await _probe_listen(cfg.host, cfg.port)
        device = SimDevice(
            id=cfg.unit_id,
            simdata=[
                SimData(PLC_BLOCK.start, count=PLC_BLOCK.size, values=0, datatype=DataType.REGISTERS),
                SimData(CELL_BLOCK.start, count=CELL_BLOCK.size, values=0, datatype=DataType.REGISTERS),
            ],
            action=self._on_access,
        )
        server = GuardedTcpServer(device, address=(cfg.host, cfg.port), networks=cfg.client_networks(),
                                  policy=policy_for(cfg.idle_after_s), function_codes=_HOLDING_REGISTER_FCS)
        self._gate = _UnitGate(server.context, cfg.unit_id, self._refused_cell_write)
        server.context = self._gate  # type: ignore[assignment]
        self._server = server
        self._wake = asyncio.Event()
        self._fault = None
        now = self._clock()
        self._watch = HeartbeatWatch(cfg.heartbeat_timeout_s, now if watch_heartbeat else None)
        self._next_beat_s = now
        try:
            # The first scan fills the cell block before anyone can connect: the PLC's first read
            # already shows the cell's state (Aborted after a start), never 0 (undefined).
            await self._scan()
        except BaseException:
            self._server = None
            await server.shutdown()
            raise
        try:
            # pymodbus returns once its listener is up, or raises RuntimeError when listen() failed
            # (it logs the OSError and returns False); bounded, so start() can never hang.
            await asyncio.wait_for(server.serve_forever(background=True), START_TIMEOUT_S)
            if server.transport is None or not getattr(server.transport, "sockets", None):
                raise RuntimeError("no listening socket")
        except (RuntimeError, OSError, asyncio.TimeoutError) as exc:
            self._server = None
            await server.shutdown()
            if isinstance(exc, asyncio.TimeoutError):
                exc = TimeoutError(f"not listening after {START_TIMEOUT_S:g} s")
            raise _listen_error(cfg.host, cfg.port, exc) from exc
        except BaseException:  # cancelled while starting
            self._server = None
            await server.shutdown()
            raise
        self._tasks = [
            asyncio.create_task(self._scan_loop(), name="plc-scan"),
            asyncio.create_task(self._cycle.run(), name="plc-cycle-handshake"),
            asyncio.create_task(self._command.run(), name="plc-command-handshake"),
            asyncio.create_task(self._mode.run(), name="plc-mode-handshake"),
        ]
        for task in self._tasks:
            task.add_done_callback(self._task_ended)
        log.info("PLC interface listening on %s:%d (unit id %d, word order %s; %s)",
                 cfg.host, self.port, cfg.unit_id, cfg.float_word_order, cfg.clients_note())

    def watch_heartbeat(self) -> None:
        """Open the PLC heartbeat's first window now (after ``start(watch_heartbeat=False)``); once."""
        self._watch.arm(self._clock())

    async def stop(self) -> None:
        """Stop the handshakes and close the listener and every PLC connection. Cycles keep running
        in the cell; a restarted server picks their results up by cycle_req_id."""
        tasks, self._tasks = self._tasks, []
        pending = set(tasks)
        while pending:  # a cancel can be lost (asyncio.wait_for on 3.11 swallows one that meets its inner answer): send it again
            for task in pending:
                task.cancel()
            _, pending = await asyncio.wait(pending, timeout=0.1)
        await asyncio.gather(*tasks, return_exceptions=True)
        server, self._server = self._server, None
        if server is not None:
            await server.shutdown()
            log.info("PLC interface stopped")

    async def __aenter__(self) -> PlcServer:
        await self.start()
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        await self.stop()

    # --- observation ------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        return self._server is not None

    @property
    def port(self) -> int:
        """The TCP port actually bound (differs from the config when it asked for port 0)."""
        if self._server is None or self._server.transport is None:
            raise RuntimeError("the PLC server is not running")
        return int(self._server.transport.sockets[0].getsockname()[1])  # type: ignore[attr-defined]

    @property
    def refused_writes(self) -> int:
        """PLC writes into the cell block refused since construction."""
        return self._refused_writes

    @property
    def other_unit_requests(self) -> dict[int, int]:
        """Requests to another unit id than ``[plc] unit_id`` (answered with exception 11), by unit id."""
        return {} if self._gate is None else dict(self._gate.refused)

    @property
    def plc_link_alive(self) -> bool:
        return self._watch.alive

    @property
    def fault(self) -> BaseException | None:
        """Why a handshake task died, if one did (the cell heartbeat then stops)."""
        return self._fault

    # --- internals --------------------------------------------------------------------------

    def _task_ended(self, task: asyncio.Task[None]) -> None:
        if task.cancelled():
            return
        exc = task.exception()
        if exc is not None:
            self._fault = exc
            log.critical("PLC interface task %s died; the cell heartbeat stops", task.get_name(),
                         exc_info=exc)

    async def _on_access(self, func_code: int, _start: int, address: int, count: int,
                         _registers: list[int], set_values: list[int] | list[bool] | None) -> ExcCodes | None:
        """pymodbus calls this before every datastore access, the cell's own included."""
        if func_code not in _HOLDING_REGISTER_FCS:
            return ExcCodes.ILLEGAL_FUNCTION
        if set_values is None:
            return None
        n = len(set_values) if set_values else count
        if _CELL_WRITING.get():
            return ExcCodes.ILLEGAL_ADDRESS if PLC_BLOCK.overlaps(address, n) else None
        if (refused := self._refused_cell_write(func_code, address, n)) is not None:
            return refused
        self._wake.set()
        return None

    def _refused_cell_write(self, func_code: int, address: int, n: int) -> ExcCodes | None:
        """A PLC's register write reaching into the cell block, from anywhere: refused (exception 2) and counted."""
        if func_code not in _HOLDING_REGISTER_FCS or _CELL_WRITING.get() or not CELL_BLOCK.overlaps(address, n):
            return None
        self._refused_writes += 1
        level = logging.WARNING if self._refused_writes % 1000 == 1 else logging.DEBUG
        log.log(level, "refused PLC write (FC%d) to %d..%d: the cell block is written only by the "
                "cell (%d refused so far)", func_code, address, address + n - 1, self._refused_writes)
        self._wake.set()
        return ExcCodes.ILLEGAL_ADDRESS

    async def _flush(self) -> None:
        """Put the whole cell image on the wire in one datastore write (the PLC never sees half)."""
        if self._server is None:
            return
        regs = self._image.registers(self._config.float_word_order)
        token = _CELL_WRITING.set(True)
        try:
            await self._server.async_setValues(self._config.unit_id, _FC_WRITE_MULTIPLE, CELL_BLOCK.start, regs)
        finally:
            _CELL_WRITING.reset(token)

    async def _read_plc_block(self) -> PlcInputs:
        assert self._server is not None
        regs = await self._server.async_getValues(self._config.unit_id, _FC_READ_HOLDING,
                                                  PLC_BLOCK.start, PLC_BLOCK.size)
        return PlcInputs.from_decoded(decode_block(PLC_BLOCK, [int(r) for r in regs],
                                                   self._config.float_word_order))

    async def _scan_loop(self) -> None:
        period = self._config.scan_period_s
        while True:
            try:
                await asyncio.wait_for(self._wake.wait(), period)
            except asyncio.TimeoutError:
                pass
            self._wake.clear()
            await self._scan()

    async def _scan(self) -> None:
        inputs = await self._read_plc_block()
        now = self._clock()
        change = self._watch.observe(inputs.plc_heartbeat, now)
        if change is not None:
            self._report_link(change.event, change.silent_for_s)
        status = self._read_status()
        update: dict[str, object] = {"refused_write_count": self._refused_writes & 0xFFFF}
        flags = {"plc_heartbeat_ok": self._watch.alive, "ready": False, "robot_clear": False}
        if status is not None:
            update.update(state_current=int(status.state), unit_mode_current=int(status.unit_mode),
                          cycle_step=int(status.cycle_step), stop_reason_id=status.stop_reason_id,
                          interlock_alarm_id=status.interlock_alarm_id)
            flags["ready"] = status.ready_for_cycle and self._cycle.idle and inputs.cycle_request == 0
            # never while the PLC's own cycle is accepted and not yet done, whatever the cell's pose report says
            flags["robot_clear"] = status.robot_clear and not self._image.flag("cycle_flags", "busy")
            if self._fault is None and now >= self._next_beat_s:
                self._cell_heartbeat = (self._cell_heartbeat + 1) & 0xFFFF
                period = self._config.cell_heartbeat_period_s
                self._next_beat_s += period
                if self._next_beat_s <= now:  # fell behind (a stall): restart the cadence
                    self._next_beat_s = now + period
                update["cell_heartbeat"] = self._cell_heartbeat
        update["cycle_flags"] = flags
        self._image.update(**update)  # type: ignore[arg-type]
        await self._flush()
        await self._feed.publish(inputs)

    def _read_status(self) -> CellStatus | None:
        try:
            status = self._cell.status()
            if not isinstance(status, CellStatus):
                raise TypeError(f"status() returned {type(status).__name__}, not CellStatus")
        except Exception:
            if not self._status_failing:
                log.exception("the cell's status() failed; the cell heartbeat stops until it answers")
            self._status_failing = True
            return None
        if self._status_failing:
            log.info("the cell's status() answers again")
        self._status_failing = False
        return status

    def _report_link(self, event: LinkEvent, silent_for_s: float) -> None:
        try:
            if event is LinkEvent.LOST:
                log.warning("PLC heartbeat lost: plc_heartbeat unchanged for %.2f s", silent_for_s)
                self._cell.plc_link_lost(silent_for_s)
            else:
                log.info("PLC heartbeat %s", "started" if event is LinkEvent.STARTED else "restored")
                self._cell.plc_link_restored()
        except Exception:
            log.exception("the cell failed to take the PLC link report (%s)", event.value)
