"""uvicorn's h11 protocol with guards against connections that hold the process's file descriptors.

uvicorn closes an idle keep-alive connection only after a response: one that never sends a request
(or sends half of one) stays open for ever, and a thousand of them leave the process without file
descriptors (the Modbus server, the store and the cycle's images too). Here a connection must
deliver a whole request within ``request_timeout_s`` of opening or of its last response, and a
connection beyond the cap (in all, or from one client host) is closed as soon as it is accepted.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

log = logging.getLogger(__name__)

MAX_CONNECTIONS = 1024
"""At most this many HTTP connections, and at most a quarter of the process's open files limit."""
WARN_EVERY_S = 60.0


def connection_limits(open_files: int) -> tuple[int, int]:
    """(connections in all, connections from one client host) for a process allowed ``open_files`` files."""
    total = max(16, min(MAX_CONNECTIONS, open_files // 4))
    return total, max(8, total // 4)


class GuardedH11Protocol(H11Protocol):
    """H11Protocol with a connection cap (in all and per client host) and a deadline for each request."""

    max_connections = MAX_CONNECTIONS
    max_per_host = MAX_CONNECTIONS // 4
    request_timeout_s = 5.0
    _warned: dict[str, float] = {}

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        refusal = self._refusal()
        if refusal is not None:
            self._warn_once(refusal)
            self.connections.discard(self)  # counted out now: a burst's refused ones must not crowd out other hosts
            transport.abort()  # no lingering close: the descriptor is freed now
            return
        self._arm_deadline()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm_deadline()
        super().connection_lost(exc)

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing():
            self._arm_deadline()

    def _refusal(self) -> str | None:
        """Why this new connection is one too many (None: it may stay)."""
        if len(self.connections) > self.max_connections:
            return f"{len(self.connections) - 1} HTTP connections are open, the most this service keeps"
        host = self.client[0] if self.client else None
        from_host = sum(1 for c in self.connections if c.client and c.client[0] == host)
        if host is not None and from_host > self.max_per_host:
            return f"{from_host - 1} HTTP connections from {host} are open, the most one host may hold"
        return None

    def _warn_once(self, refusal: str) -> None:
        host = self.client[0] if self.client else "?"
        now = time.monotonic()
        if now - self._warned.get(host, -WARN_EVERY_S) >= WARN_EVERY_S:
            if len(self._warned) > 1000:
                self._warned.clear()
            self._warned[host] = now
            log.warning("closed a new HTTP connection from %s: %s (said once a minute per host)", host, refusal)

    def _arm_deadline(self) -> None:
        self._disarm_deadline()
        self._deadline = self.loop.call_later(self.request_timeout_s, self._on_deadline)

    def _disarm_deadline(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _on_deadline(self) -> None:
        """Close the connection if the client still owes its request's head, or its body before any response."""
        self._deadline = None
        waiting_head = self.conn.their_state is h11.IDLE
        waiting_body = self.conn.their_state is h11.SEND_BODY and not (self.cycle and self.cycle.response_started)
        if (waiting_head or waiting_body) and not self.transport.is_closing():
            self.transport.close()  # connection_lost tells a request waiting for its body


def guarded_protocol(*, max_connections: int, max_per_host: int, request_timeout_s: float) -> type[GuardedH11Protocol]:
    """A :class:`GuardedH11Protocol` class with these limits (uvicorn's ``http`` setting)."""
    limits = {"max_connections": max_connections, "max_per_host": max_per_host, "request_timeout_s": request_timeout_s,
              "_warned": {}}  # fmt: skip
    return type("GuardedH11Protocol", (GuardedH11Protocol,), limits)
