"""The Modbus TCP connections the cell holds: caps, TCP keepalive, warnings per peer, a listener that rests.

A connection costs the service a file descriptor, and Modbus TCP clients leave them behind: a PLC that loses
power or its cable leaves a half-open one, an HMI that opens a connection per poll may never close them. The
Modbus Messaging on TCP/IP Implementation Guide (V1.0b, 4.2.1) advises TCP keepalive and a connection limit
that closes the oldest unused connection to admit a new one. Here: at most ``max_connections`` in all and
``max_per_host`` from one address (from the open files limit, as the REST server's caps); beyond a cap the
connection that has gone longest without a request, idle at least ``EVICT_MIN_IDLE_S``, is closed for the new
one, else the new one is refused. The listening socket rests ``ACCEPT_REST_S`` when the process has no file
descriptor left, where asyncio 3.11 would retry the accept in a busy loop.
"""

from __future__ import annotations

import errno
import logging
import resource
import socket
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Protocol

log = logging.getLogger(__name__)

MAX_CONNECTIONS = 256
"""At most this many Modbus TCP connections, and at most an eighth of the process's open files limit."""
KEEPALIVE_IDLE_S = 30
"""TCP keepalive: first probe after this long without traffic, then every ``KEEPALIVE_INTERVAL_S``."""
KEEPALIVE_INTERVAL_S = 10
KEEPALIVE_COUNT = 3
"""Unanswered probes before the OS drops the connection (a vanished peer goes within 60 s)."""
EVICT_MIN_IDLE_S = 1.0
"""A connection must have been without a request this long to be closed for a new one (a flood's fresh
connections are refused instead of pushing each other out)."""
NOTE_EVERY_S = 300.0
"""A warning about one peer is repeated at most this often, with the count since."""
ACCEPT_REST_S = 0.5
"""How long the listener stops accepting after the process ran out of file descriptors."""
_OUT_OF_RESOURCES = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})


@dataclass(frozen=True)
class ConnectionPolicy:
    """Caps (connections) and the idle timeout (s) of the Modbus TCP server."""

    max_connections: int
    max_per_host: int
    idle_timeout_s: float


def connection_limits(open_files: int) -> tuple[int, int]:
    """(connections in all, connections from one address) for a process allowed ``open_files`` files."""
    total = max(8, min(MAX_CONNECTIONS, open_files // 8))
    return total, max(4, total // 4)


def open_files_limit() -> int:
    """This process's soft limit of open files (the service raises it to the hard one at start)."""
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    return int(soft) if soft != resource.RLIM_INFINITY else 1 << 20


def policy_for(idle_timeout_s: float, open_files: int | None = None) -> ConnectionPolicy:
    """The policy for ``idle_timeout_s`` and the open files limit (this process's, if not given)."""
    total, per_host = connection_limits(open_files_limit() if open_files is None else open_files)
    return ConnectionPolicy(total, per_host, idle_timeout_s)


def set_keepalive(sock: Any) -> None:
    """TCP keepalive on an accepted socket (the OS then drops a peer that vanished without a FIN)."""
    if sock is None:
        return
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        for name, value in (("TCP_KEEPIDLE", KEEPALIVE_IDLE_S), ("TCP_KEEPINTVL", KEEPALIVE_INTERVAL_S),
                            ("TCP_KEEPCNT", KEEPALIVE_COUNT)):
            if hasattr(socket, name):
                sock.setsockopt(socket.IPPROTO_TCP, getattr(socket, name), value)
    except OSError as err:  # the peer reset it already: the connection ends anyway
        log.debug("TCP keepalive not set on a Modbus TCP connection: %s", err)


def host_of(peer: Any) -> str:
    """The address part of asyncio's peername ("?" when unknown)."""
    try:
        return str(peer[0])
    except (TypeError, IndexError):
        return "?"


class PeerNotes:
    """Warnings about peers: the first of each kind per address, then at most every ``NOTE_EVERY_S`` with a count."""

    def __init__(self, every_s: float = NOTE_EVERY_S, clock: Any = time.monotonic) -> None:
        self._every_s = every_s
        self._clock = clock
        self._said: dict[tuple[str, str], tuple[float, int]] = {}  # (kind, host) -> (when said, held back since)

    def note(self, kind: str, host: str, message: str, *args: object) -> None:
        now = self._clock()
        said = self._said.get((kind, host))
        if said is not None and now - said[0] < self._every_s:
            self._said[(kind, host)] = (said[0], said[1] + 1)
            log.debug(message, *args)
            return
        if len(self._said) > 1000:
            self._said.clear()
        self._said[(kind, host)] = (now, 0)
        more = f" ({said[1]} more from {host} in the last {now - said[0]:.0f} s)" if said and said[1] else ""
        log.warning(message + "%s", *args, more)


class Connection(Protocol):
    """What the table needs of a connection."""

    host: str
    last_request: float

    @property
    def busy(self) -> bool: ...

    def drop(self, why: str) -> None: ...


class ConnectionTable:
    """The open connections, admitted within the policy's caps."""

    def __init__(self, policy: ConnectionPolicy, notes: PeerNotes) -> None:
        self.policy = policy
        self.notes = notes
        self._open: dict[Connection, None] = {}  # in order of admission

    def __len__(self) -> int:
        return len(self._open)

    def admit(self, conn: Connection, now: float) -> bool:
        """Whether ``conn`` may stay: beyond a cap the oldest idle connection in its scope is closed for it,
        and without one it is refused (False, logged per peer)."""
        same_host = [c for c in self._open if c.host == conn.host]
        if len(same_host) >= self.policy.max_per_host:
            scope, within = f"{len(same_host)} from {conn.host}, the most one address may hold", same_host
        elif len(self._open) >= self.policy.max_connections:
            scope, within = f"{len(self._open)} in all, the most the cell keeps", list(self._open)
        else:
            self._open[conn] = None
            return True
        victim = self._oldest_idle(within, now)
        if victim is None:
            self.notes.note("refused", conn.host, "refused a new Modbus TCP connection from %s: %d connections "
                            "open (%s), each with a request in the last %g s", conn.host, len(within), scope,
                            EVICT_MIN_IDLE_S)  # fmt: skip
            return False
        self.notes.note("evicted", victim.host, "closed the Modbus TCP connection from %s without a request for %.0f s "
                        "to admit a new one from %s: %s (the oldest unused goes first)", victim.host,
                        now - victim.last_request, conn.host, scope)  # fmt: skip
        victim.drop("evicted")
        self.leave(victim)
        self._open[conn] = None
        return True

    def leave(self, conn: Connection) -> None:
        self._open.pop(conn, None)

    @staticmethod
    def _oldest_idle(conns: Iterable[Connection], now: float) -> Connection | None:
        idle = [c for c in conns if not c.busy and now - c.last_request >= EVICT_MIN_IDLE_S]
        return min(idle, key=lambda c: c.last_request) if idle else None


class RestingListenSocket(socket.socket):
    """A listening socket whose ``accept`` rests ``ACCEPT_REST_S`` after the process ran out of file descriptors.

    asyncio 3.11 answers EMFILE by retrying a second later, but goes on calling accept in the same pass, and every
    failure schedules another retry: the loop spins (hundreds of thousands of errors a minute). Here the first
    failure is raised (asyncio pauses the listener), the rest of the pass reads as "no connection waiting"."""

    _rest_until = 0.0

    def accept(self) -> tuple[socket.socket, Any]:
        now = time.monotonic()
        if now < self._rest_until:
            raise BlockingIOError(errno.EAGAIN, "resting: the process has no file descriptor left")
        try:
            return super().accept()
        except OSError as exc:
            if exc.errno in _OUT_OF_RESOURCES:
                self._rest_until = now + ACCEPT_REST_S
            raise


def listening_sockets(infos: Iterable[tuple[Any, ...]]) -> list[RestingListenSocket]:
    """Bound listening sockets for getaddrinfo's answers, as asyncio's create_server makes them (SO_REUSEADDR,
    IPv6 ones v6-only); OSError with the cause's errno when one cannot bind."""
    made: list[RestingListenSocket] = []
    try:
        for family, kind, proto, address in dict.fromkeys((i[0], i[1], i[2], i[4]) for i in infos):
            sock = RestingListenSocket(family, kind, proto)
            made.append(sock)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6 and hasattr(socket, "IPPROTO_IPV6"):
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind(address)
    except BaseException:
        for sock in made:
            sock.close()
        raise
    return made
