"""The HTTP server of the service (uvicorn), stopped by SIGTERM exactly as by SIGINT.

uvicorn, left to itself, catches SIGINT/SIGTERM while it serves and raises the signal again
once its HTTP server is down; for SIGTERM (what systemd sends) that kills the process before
the service has stopped its devices, ended a running job and closed the store. Here a signal
only asks the server to exit, the event streams are ended at once (an open dashboard must not
hold the shutdown up), and the caller learns which signal it was.
"""

from __future__ import annotations

import contextlib
import signal
import socket
import threading
from collections.abc import Callable, Generator
from types import FrameType
from typing import Any

import uvicorn

HANDLED = (signal.SIGINT, signal.SIGTERM)
GRACEFUL_SHUTDOWN_S = 3.0


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


def make_server(app: Any, host: str, port: int, on_exit: Callable[[], Any]) -> ServiceServer:
    config = uvicorn.Config(app, host=host, port=port, log_level="warning", log_config=None, lifespan="off",
                            timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S)  # fmt: skip
    return ServiceServer(config, on_exit)
