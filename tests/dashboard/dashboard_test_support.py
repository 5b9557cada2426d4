"""The simulated cell service with its HTTP server on a free loopback port, for the dashboard tests.

The service runs in a background thread with its own asyncio loop (the real composition from
``build_service`` and the real ``create_app`` under uvicorn), so a test can drive it over HTTP
like any client, drive a headless Chromium at it, and still reach into the orchestrator (e.g. to
raise an alarm at a chosen moment) through :meth:`LiveCell.run`.
"""

from __future__ import annotations

import asyncio
import shutil
import socket
import threading
import time
from collections.abc import Coroutine
from pathlib import Path
from typing import Any, TypeVar
from urllib.parse import urlsplit

import httpx
import uvicorn
from service_test_support import sim_config as service_sim_config
from shared_support import on_ci

from cellctl.api.app import create_app
from cellctl.config import CellConfig
from cellctl.service import build_service
from cellctl.service.compose import Service

ROOT = Path(__file__).resolve().parents[2]
TOKEN = "sim-operator-token-change-me"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
ARTIFACTS = ROOT / "test-artifacts" / "dashboard"
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
LOOPBACK_HOSTS = {"127.0.0.1", "localhost", "[::1]", "::1"}

T = TypeVar("T")


def sim_config(**sections: dict[str, Any]) -> CellConfig:
    """The service harness's config with the PLC server off by default (no port to clash)."""
    sections.setdefault("plc", {"enabled": False})
    return service_sim_config(**sections)


def chromium_missing_reason() -> str | None:
    """Why the browser tests cannot run here, or None. On CI (CI=true) a missing browser is a failure."""
    if CHROMIUM.is_file() and shutil.which(str(CHROMIUM)):
        return None
    reason = f"{CHROMIUM} is missing: install Debian's chromium (apt-get install -y chromium)"
    if on_ci():
        raise RuntimeError(reason + " (CI must install it)")
    return reason


def browser_marks(timeout_s: float = 120) -> list[Any]:
    """A browser test module's marks: skipped without Chromium (off CI), and a time limit."""
    import pytest

    missing = chromium_missing_reason()
    return [pytest.mark.skipif(missing is not None, reason=missing or ""), pytest.mark.timeout(timeout_s)]


class LiveCell:
    """The simulated cell served over HTTP on 127.0.0.1 from a background thread."""

    def __init__(self, workdir: Path, config: CellConfig | None = None) -> None:
        self.workdir = workdir
        self.config = config or sim_config()
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


def settle(client: httpx.Client, deadline_s: float = 10.0) -> str:
    """The PackML state once the acting states (..ING) have ended."""
    end = time.monotonic() + deadline_s
    while True:
        state = str(client.get("/status").json()["state"])
        if not state.endswith("ING") or time.monotonic() > end:
            return state
        time.sleep(0.02)


RECOVERY = {"ABORTED": "clear", "STOPPED": "reset", "IDLE": "start", "HELD": "unhold", "SUSPENDED": "unsuspend", "COMPLETE": "reset"}


def to_execute(client: httpx.Client) -> None:
    """Bring the cell to Execute from wherever it is, acknowledging alarms on the way."""
    for _ in range(8):
        state = settle(client)
        if state == "EXECUTE":
            return
        client.post("/alarms/acknowledge-all", headers=AUTH).raise_for_status()
        r = client.post(f"/commands/{RECOVERY[state]}", headers=AUTH)
        assert r.status_code == 200, r.text
    raise AssertionError(f"the cell did not reach EXECUTE, it is {settle(client)}")


def to_aborted(client: httpx.Client) -> None:
    if settle(client) != "ABORTED":
        assert client.post("/commands/abort", headers=AUTH).status_code == 200
    assert settle(client) == "ABORTED"


def install_cycles(client: httpx.Client, key: str, parts: list[tuple[str, str | None]]) -> list[dict[str, Any]]:
    """Run one cycle per (part id, car id) to its end (``wait=true``); each must install. Their records."""
    to_execute(client)
    out = []
    for i, (part_id, car_id) in enumerate(parts):
        body: dict[str, Any] = {"recipe": "side-window", "part_id": part_id}
        if car_id is not None:
            body["car_id"] = car_id
        r = client.post(
            "/cycle", params={"wait": "true", "timeout_s": 60}, json=body, headers={**AUTH, "Idempotency-Key": f"{key}-{i}"}
        )
        assert r.status_code == 200, r.text
        assert r.json()["state"] == "done", r.json()
        out.append(dict(r.json()))
    return out


def wait_cycle(client: httpx.Client, cycle_id: int, deadline_s: float = 30.0) -> dict[str, Any]:
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        rec = client.get(f"/cycles/{cycle_id}").json()
        if rec["state"] in ("done", "failed", "interrupted"):
            return dict(rec)
        time.sleep(0.05)
    raise AssertionError(f"cycle {cycle_id} did not finish within {deadline_s} s")


class PageLog:
    """Every request the page made, what the browser console reported as an error, and full page loads."""

    def __init__(self) -> None:
        self.requests: list[str] = []
        self.errors: list[str] = []
        self.loads = 0  # full document loads (hash changes do not count)

    def foreign(self) -> list[str]:
        return [u for u in self.requests if urlsplit(u).scheme not in ("data", "blob") and urlsplit(u).hostname not in LOOPBACK_HOSTS]


def shot(pg: Any, name: str) -> Path:
    """A full-page screenshot into test-artifacts/dashboard/."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    path = ARTIFACTS / name
    pg.screenshot(path=str(path), full_page=True)
    return path
