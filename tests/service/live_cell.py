"""The simulated cell served over HTTP by uvicorn on 127.0.0.1, from a background thread: for the tests whose
peer is a real HTTP client in this process (the CLI, httpx, a browser)."""

from __future__ import annotations

import asyncio
import socket
import threading
import time
from collections.abc import Coroutine
from pathlib import Path
from typing import Any, TypeVar

import uvicorn
from service_test_support import sim_config

from cellctl.api.app import create_app
from cellctl.config import CellConfig
from cellctl.service import build_service
from cellctl.service.compose import Service

T = TypeVar("T")


class LiveCell:
    """The simulated cell served over HTTP on 127.0.0.1 from a background thread."""

    def __init__(self, workdir: Path, config: CellConfig | None = None) -> None:
        self.workdir = workdir
        self.config = config or sim_config(plc={"enabled": False})  # no PLC port to clash
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name="cell-service", daemon=True)
        self.service: Service | None = None
        self.port = 0
        self._server: uvicorn.Server | None = None
        self._serve_task: asyncio.Task[None] | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def orch(self) -> Any:
        assert self.service is not None
        return self.service.orchestrator

    def run(self, coro: Coroutine[Any, Any, T], timeout_s: float = 30.0) -> T:
        """Run a coroutine in the service's loop and return its result."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout_s)

    def start(self) -> None:
        self.thread.start()
        self.run(self._start(), timeout_s=90.0)

    def __enter__(self) -> LiveCell:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stop(self) -> None:
        try:
            self.run(self._stop(), timeout_s=30.0)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self.thread.join(10.0)
            if not self.thread.is_alive():
                self.loop.close()

    async def _start(self) -> None:
        self.service = await build_service(self.config, workdir=self.workdir)
        await self.service.start()
        await self._start_http()

    async def _stop(self) -> None:
        await self._stop_http()
        if self.service is not None:
            await self.service.stop()

    async def _start_http(self) -> None:
        assert self.service is not None
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("127.0.0.1", self.port))
        self.port = int(sock.getsockname()[1])
        app = create_app(self.service.orchestrator, self.service.config.api, self.service.jobs)
        self._server = uvicorn.Server(
            uvicorn.Config(app, lifespan="off", log_level="warning", timeout_graceful_shutdown=1)
        )
        self._serve_task = asyncio.create_task(self._server.serve(sockets=[sock]))
        deadline = time.monotonic() + 20.0
        while not self._server.started:
            if self._serve_task.done():
                self._serve_task.result()
                raise RuntimeError("uvicorn stopped before it started")
            if time.monotonic() > deadline:
                raise RuntimeError("uvicorn did not start within 20 s")
            await asyncio.sleep(0.02)

    async def _stop_http(self) -> None:
        if self._server is None or self._serve_task is None:
            return
        self._server.should_exit = True
        await asyncio.wait_for(self._serve_task, 15.0)
        self._server = None
        self._serve_task = None

    def stop_http(self) -> None:
        """Take the HTTP server away (the cell keeps running), as a lost network would."""
        self.run(self._stop_http())

    def start_http(self) -> None:
        """Serve HTTP again on the same port."""
        self.run(self._start_http())
