"""The HTTP server of the service (uvicorn), stopped by SIGTERM exactly as by SIGINT.

uvicorn, left to itself, catches SIGINT/SIGTERM while it serves and raises the signal again
once its HTTP server is down; for SIGTERM (what systemd sends) that kills the process before
the service has stopped its devices, ended a running job and closed the store. Here a signal
only asks the server to exit, the event streams are ended at once (an open dashboard must not
hold the shutdown up), and the caller learns which signal it was. Idle and crowding connections are
closed (``cellctl.service.http_guard``): no host can take the process's file descriptors by holding them.
"""

from __future__ import annotations

import contextlib
import logging
import resource
import signal
import socket
import threading
from collections.abc import Callable, Generator
from pathlib import Path
from types import FrameType
from typing import Any

import uvicorn

from cellctl.service.http_guard import connection_limits, guarded_protocol

HANDLED = (signal.SIGINT, signal.SIGTERM)
GRACEFUL_SHUTDOWN_S = 3.0
KEEP_ALIVE_S = 5
"""An idle keep-alive connection is closed this long after its last response."""
REQUEST_TIMEOUT_S = 5.0
"""A connection must deliver a whole request (head and body) this soon after it opened or its last response."""
log = logging.getLogger(__name__)


class ServiceServer(uvicorn.Server):
    """A uvicorn server whose SIGINT/SIGTERM end ``serve()`` normally; ``signal_received`` says which came."""

    def __init__(self, config: uvicorn.Config, on_exit: Callable[[], Any]) -> None:
        super().__init__(config)
        self.on_exit = on_exit
        self.signal_received: int | None = None

    @contextlib.contextmanager
    def capture_signals(self) -> Generator[None, None, None]:
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        original = {sig: signal.signal(sig, self.handle_exit) for sig in HANDLED}
        try:
            yield
        finally:
            for sig, handler in original.items():
                signal.signal(sig, handler)

    async def serve(self, sockets: list[socket.socket] | None = None) -> None:
        """uvicorn's, but a port it cannot bind ends it with ``started`` False (the service then names the
        setting to change) instead of its ``sys.exit``, which would leave the event loop at once."""
        try:
            await super().serve(sockets)
        except SystemExit:
            if self.started:
                raise

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        if self.should_exit and sig == signal.SIGINT:
            self.force_exit = True  # a second Ctrl-C: do not wait for open connections
        self.signal_received = self.signal_received or sig
        self.should_exit = True
        self.on_exit()


ACCEPT_BACKLOG = 64
"""The listen backlog, which is also how many connections asyncio accepts at once before the guard judges any:
a flood of connections takes at most this many descriptors beyond the caps (uvicorn's default is 2048)."""


def raise_open_files_limit() -> int:
    """Raise this process's soft limit of open files to its hard limit (systemd's default soft limit is 1024);
    the soft limit now."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and soft != hard:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
        except (OSError, ValueError) as err:
            log.warning("cannot raise the open files limit from %d to %d (%s); LimitNOFILE in the unit sets it", soft, hard, err)
    return int(soft) if soft != resource.RLIM_INFINITY else 1 << 20


def make_server(app: Any, host: str, port: int, on_exit: Callable[[], Any],
                tls: tuple[Path, Path] | None = None) -> ServiceServer:  # fmt: skip
    """The service's uvicorn server: HTTP connections capped by the open files limit (in all and per client host),
    and closed when they send no whole request within ``REQUEST_TIMEOUT_S``; HTTPS only with ``tls`` (the PEM
    certificate and its key, checked beforehand by ``ApiConfig.tls_problems``)."""
    total, per_host = connection_limits(raise_open_files_limit())
    protocol = guarded_protocol(max_connections=total, max_per_host=per_host, request_timeout_s=REQUEST_TIMEOUT_S)
    cert, key = tls if tls is not None else (None, None)
    config = uvicorn.Config(app, host=host, port=port, log_level="warning", log_config=None, lifespan="off",
                            http=protocol, timeout_keep_alive=KEEP_ALIVE_S, limit_concurrency=total + 1,
                            backlog=ACCEPT_BACKLOG, timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S,
                            ssl_certfile=cert, ssl_keyfile=key)  # fmt: skip
    return ServiceServer(config, on_exit)
