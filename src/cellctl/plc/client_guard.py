"""Modbus TCP clients by address: ``[plc] allowed_clients`` decides who may connect at all.

Modbus TCP has no authentication; anyone who reaches the port could command the cell. A connection
from an address outside ``allowed_clients`` is closed as soon as it is accepted, before a byte is
read, and logged once per address. Empty ``allowed_clients`` lets every client in (as before).
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
from collections.abc import Sequence
from typing import Any

from pymodbus.server import ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler

log = logging.getLogger(__name__)

Network = ipaddress.IPv4Network | ipaddress.IPv6Network
MAX_REMEMBERED = 1000


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
    """pymodbus's per-connection handler, closed at once when its peer is not an allowed client."""

    guard: ClientGuard

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        super().connection_made(transport)
        peer = transport.get_extra_info("peername")
        if not client_allowed(peer, self.guard.networks):
            self.guard.refused(peer)
            self.close()  # closes the transport and leaves the server's connection table


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


class GuardedTcpServer(ModbusTcpServer):
    """``ModbusTcpServer`` whose connections from addresses outside ``networks`` are closed when accepted."""

    def __init__(self, *args: Any, networks: Sequence[Network] = (), **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.guard = ClientGuard(networks)

    def callback_new_connection(self) -> ServerRequestHandler:
        handler = _GuardedHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)
        handler.guard = self.guard
        return handler
