"""The Modbus TCP server's connections: who may connect, how many, how long idle, and how their frames are read.

Modbus TCP has no authentication; anyone who reaches the port could command the cell. A connection
from an address outside ``[plc] allowed_clients`` is closed as soon as it is accepted, before a byte is
read, and logged once per address. Empty ``allowed_clients`` lets every client in (as before).

pymodbus 3.16's handler serves one frame per receive and clears its buffer on every answer, never closes
a connection, and answers an undecodable request with function code 0x80. Here (``_GuardedHandler``):

- every complete MBAP frame received is served, in order, one after the other, each answered with its
  transaction id; a partial frame waits for the rest (several requests outstanding, or Nagle);
- a frame with a protocol id other than 0 or an MBAP length outside 2..254 cannot be Modbus TCP: the
  frames before it are answered, then the connection is closed (logged once per peer);
- a function code outside ``function_codes`` gets exception 1 and one that does not decode (a quantity
  out of range, a short PDU) exception 3, each with the request's function code | 0x80;
- TCP keepalive, ``[plc] idle_timeout_s`` without a request closes the connection, and connection caps
  (``cellctl.plc.connections``).
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import socket
from collections import deque
from collections.abc import Collection, Sequence
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.pdu import ExceptionResponse
from pymodbus.server import ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler

from cellctl.plc.connections import (
    ConnectionPolicy,
    ConnectionTable,
    PeerNotes,
    host_of,
    listening_sockets,
    policy_for,
    set_keepalive,
)

log = logging.getLogger(__name__)

Network = ipaddress.IPv4Network | ipaddress.IPv6Network
MAX_REMEMBERED = 1000
MBAP_HEADER = 6
"""Transaction id, protocol id and length (bytes); the length counts the unit id and the PDU that follow."""
MBAP_LENGTHS = range(2, 255)
"""Valid MBAP lengths: unit id and function code at least, a 253-byte PDU at most."""
MAX_PENDING = 16
"""Frames queued per connection before the cell stops reading from it (TCP then holds the client back)."""
ACCEPT_BACKLOG = 64


def client_allowed(peer: Any, networks: Sequence[Network]) -> bool:
    """Whether the peer address ``peer`` (asyncio's peername) lies in one of ``networks`` (none given: any peer)."""
    if not networks:
        return True
    try:
        address = ipaddress.ip_address(peer[0])
    except (TypeError, ValueError, IndexError):
        return False
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        address = address.ipv4_mapped  # an IPv4 client of a dual-stack listener
    return any(address in net for net in networks)


class _GuardedHandler(ServerRequestHandler):
    """pymodbus's per-connection handler: address guard, caps, idle timeout and MBAP framing of its own."""

    guard: ClientGuard
    table: ConnectionTable
    function_codes: Collection[int] | None

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self.host = "?"
        self.last_request = self.loop.time()  # the last complete request received or answered
        self.max_buffer_size = 1 << 19  # the buffer keeps one partial frame; asyncio reads 256 KiB at most at once
        self._frames: deque[bytes] = deque()
        self._serving: asyncio.Task[None] | None = None
        self._executing = False
        self._writable = asyncio.Event()
        self._writable.set()
        self._reading_paused = False
        self._close_when_served = False
        self._idle_timer: asyncio.TimerHandle | None = None
        self._admitted = False

    # --- connection life -------------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        super().connection_made(transport)
        peer = transport.get_extra_info("peername")
        self.host = host_of(peer)
        if not client_allowed(peer, self.guard.networks):
            self.guard.refused(peer)
            self.close()  # closes the transport and leaves the server's connection table
            return
        if not self.table.admit(self, self.loop.time()):
            transport.abort()  # no lingering close: the descriptor is free now
            self.close()
            return
        self._admitted = True
        set_keepalive(transport.get_extra_info("socket"))
        self._arm_idle(self.table.policy.idle_timeout_s)

    def connection_lost(self, exc: Exception | None) -> None:
        self._forget()
        super().connection_lost(exc)

    def close(self, reconnect: bool = False) -> None:
        self._forget()
        super().close(reconnect=reconnect)

    def _forget(self) -> None:
        if self._idle_timer is not None:
            self._idle_timer.cancel()
            self._idle_timer = None
        if self._serving is not None and self._serving is not asyncio.current_task():
            self._serving.cancel()
        self._serving = None
        self._frames.clear()
        if self._admitted:
            self._admitted = False
            self.table.leave(self)

    @property
    def busy(self) -> bool:
        """Serving a request now (not idle, whatever the time since the last one)."""
        return self._executing

    def drop(self, why: str) -> None:
        """Close now; reset when answers are still unsent (a peer that does not read would hold it open)."""
        log.debug("closing the Modbus TCP connection from %s: %s", self.host, why)
        transport = self.transport
        if transport is not None and transport.get_write_buffer_size():  # type: ignore[attr-defined]
            transport.abort()
        self.close()

    def _arm_idle(self, delay_s: float) -> None:
        self._idle_timer = self.loop.call_later(delay_s, self._check_idle)

    def _check_idle(self) -> None:
        self._idle_timer = None
        if self.transport is None:
            return
        timeout = self.table.policy.idle_timeout_s
        idle = self.loop.time() - self.last_request
        if self._executing or idle < timeout:
            self._arm_idle(timeout if self._executing else timeout - idle)
            return
        self.table.notes.note("idle", self.host, "closed a Modbus TCP connection from %s: no request for %.0f s "
                              "([plc] idle_timeout_s = %g s)", self.host, idle, timeout)  # fmt: skip
        self.drop("idle")

    # --- frames ----------------------------------------------------------------------------

    def callback_data(self, data: bytes, addr: tuple[Any, ...] | None = None) -> int:
        """Queue every complete frame of ``data`` (pymodbus keeps the rest for the next receive); the bytes used."""
        used = self._split(data)
        if self._frames and self._serving is None and self.transport is not None:
            self._serving = self.loop.create_task(self._serve(), name=f"modbus-{self.host}")
        return used

    def _split(self, data: bytes) -> int:
        used = 0
        while not self._close_when_served and len(self._frames) < MAX_PENDING and len(data) - used >= MBAP_HEADER:
            protocol = int.from_bytes(data[used + 2:used + 4], "big")
            length = int.from_bytes(data[used + 4:used + 6], "big")
            if protocol != 0 or length not in MBAP_LENGTHS:
                self.table.notes.note("malformed", self.host, "closed a Modbus TCP connection from %s: a frame with "
                                      "protocol id %d and length %d is not Modbus TCP (protocol id 0, length 2..254)",
                                      self.host, protocol, length)  # fmt: skip
                self._close_when_served = True
                used = len(data)
                break
            end = used + MBAP_HEADER + length
            if end > len(data):
                break  # the rest of this frame has not arrived yet
            self._frames.append(data[used:end])
            self.last_request = self.loop.time()
            used = end
        if self.transport is not None and not self._reading_paused and (
                self._close_when_served or len(self._frames) >= MAX_PENDING):
            self._reading_paused = True
            self.transport.pause_reading()  # type: ignore[attr-defined]
        if self._close_when_served and not self._frames and self._serving is None:
            self.drop("malformed frame")
        return used

    async def _serve(self) -> None:
        """Answer the queued frames one after the other (each request complete before the next begins)."""
        while self._frames and self.transport is not None:
            await self._writable.wait()
            if not self._frames or self.transport is None:
                break
            frame = self._frames.popleft()
            self._executing = True
            try:
                await self._answer(frame)
            except Exception:  # pymodbus answers the datastore's own errors; this is anything else
                log.exception("a Modbus TCP request from %s failed; its connection is closed", self.host)
                self._close_when_served = True
                self._frames.clear()
            finally:
                self._executing = False
            self.last_request = self.loop.time()
            if self._reading_paused and not self._close_when_served and len(self._frames) < MAX_PENDING // 2:
                self.recv_buffer = self.recv_buffer[self._split(self.recv_buffer):]
                if len(self._frames) < MAX_PENDING and self.transport is not None:
                    self._reading_paused = False
                    self.transport.resume_reading()  # type: ignore[attr-defined]
        self._serving = None
        if self._close_when_served and self.transport is not None:
            self.drop("malformed frame")

    async def _answer(self, frame: bytes) -> None:
        tid = int.from_bytes(frame[0:2], "big")
        unit, pdu = frame[6], frame[7:]
        function_code = pdu[0]
        if self.function_codes is not None and function_code not in self.function_codes:
            self._exception(function_code, ExcCodes.ILLEGAL_FUNCTION, unit, tid)
            return
        request = self.framer.decoder.decode(pdu)
        if request is None or request.function_code != function_code:
            known = function_code in self.framer.decoder.list_function_codes()
            self._exception(function_code, ExcCodes.ILLEGAL_VALUE if known else ExcCodes.ILLEGAL_FUNCTION, unit, tid)
            return
        request.dev_id, request.transaction_id = unit, tid
        self.last_pdu = self.trace_pdu(False, request)
        self.last_addr = None
        await self.handle_request()

    def _exception(self, function_code: int, code: ExcCodes, unit: int, tid: int) -> None:
        self.server_send(ExceptionResponse(function_code, exception_code=code, device_id=unit, transaction=tid), None)

    # --- transport -------------------------------------------------------------------------

    def send(self, data: bytes, addr: tuple[Any, ...] | None = None) -> None:
        """pymodbus's send, which clears the receive buffer; here the frames received behind are kept."""
        kept = self.recv_buffer
        super().send(data, addr)
        self.recv_buffer = kept

    def pause_writing(self) -> None:
        self._writable.clear()  # the peer does not read its answers: serve nothing more until it does

    def resume_writing(self) -> None:
        self._writable.set()


class ClientGuard:
    """The allowed networks and the addresses refused so far (each logged once)."""

    def __init__(self, networks: Sequence[Network]) -> None:
        self.networks = tuple(networks)
        self.refused_count = 0
        self._logged: set[str] = set()

    def refused(self, peer: Any) -> None:
        self.refused_count += 1
        host = str(peer[0]) if peer else "?"
        if host not in self._logged and len(self._logged) < MAX_REMEMBERED:
            self._logged.add(host)
            log.warning("Modbus TCP connection from %s refused: not in [plc] allowed_clients (%s); "
                        "further connections from it are closed without a word", host,
                        ", ".join(map(str, self.networks)))


class _Listeners:
    """The listening servers of one address (one per address family): pymodbus's ``transport`` of the listener."""

    def __init__(self, servers: list[asyncio.Server]) -> None:
        self.servers = servers

    @property
    def sockets(self) -> tuple[Any, ...]:
        return tuple(s for server in self.servers for s in server.sockets)

    def close(self) -> None:
        for server in self.servers:
            server.close()


class GuardedTcpServer(ModbusTcpServer):
    """``ModbusTcpServer`` whose connections are guarded and framed by :class:`_GuardedHandler`.

    ``networks``: the allowed client networks (none: any); ``policy``: caps and idle timeout (default: from the
    open files limit, 60 s); ``function_codes``: those served (None: whatever pymodbus decodes)."""

    def __init__(self, *args: Any, networks: Sequence[Network] = (), policy: ConnectionPolicy | None = None,
                 function_codes: Collection[int] | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.guard = ClientGuard(networks)
        self.table = ConnectionTable(policy or policy_for(60.0), PeerNotes())
        self.function_codes = None if function_codes is None else frozenset(function_codes)
        self.call_create = self._create_listeners

    async def _create_listeners(self) -> _Listeners:
        """Listen as pymodbus would (asyncio's create_server), on sockets that rest when descriptors run out."""
        host, port = self.comm_params.source_address or ("", 502)
        loop = asyncio.get_running_loop()
        infos = await loop.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        servers: list[asyncio.Server] = []
        socks = listening_sockets(infos)
        try:
            for sock in socks:
                servers.append(await loop.create_server(self.handle_new_connection, sock=sock, backlog=ACCEPT_BACKLOG))
        except BaseException:
            for server in servers:
                server.close()
            for sock in socks[len(servers):]:
                sock.close()
            raise
        return _Listeners(servers)

    def callback_new_connection(self) -> ServerRequestHandler:
        handler = _GuardedHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)
        handler.guard = self.guard
        handler.table = self.table
        handler.function_codes = self.function_codes
        return handler
