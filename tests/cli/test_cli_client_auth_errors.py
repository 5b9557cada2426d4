"""The CLI's client against a real served cell with closed reads: the token goes on every call, a wrong token's
message names $CELLCTL_TOKEN / --token, and a malformed --url or an answer that is not JSON is one line, not a traceback."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import uvicorn
from service_test_support import TOKEN, sim_config

from cellctl.api.app import create_app
from cellctl.cli import main
from cellctl.client import CellClient, ServiceError
from cellctl.service import build_service

pytestmark = pytest.mark.timeout(120)
SIM = Path(__file__).resolve().parents[2] / "config" / "sim.toml"


@pytest.fixture(scope="module")
def closed_cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The simulated cell with [api] open_reads = false, served by uvicorn on 127.0.0.1 (a free port)."""
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    config = sim_config(plc={"enabled": False}, api={"open_reads": False})
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))

    async def start() -> tuple[object, uvicorn.Server, asyncio.Task[None]]:
        service = await build_service(config, workdir=tmp_path_factory.mktemp("closed-cell"))
        await service.start()
        app = create_app(service.orchestrator, service.config.api, service.jobs)
        server = uvicorn.Server(uvicorn.Config(app, lifespan="off", log_level="warning", timeout_graceful_shutdown=1))
        task = asyncio.create_task(server.serve(sockets=[sock]))
        while not server.started:
            await asyncio.sleep(0.02)
        return service, server, task

    async def stop(service: object, server: uvicorn.Server, task: asyncio.Task[None]) -> None:
        server.should_exit = True
        await asyncio.wait_for(task, 15.0)
        await service.stop()  # type: ignore[attr-defined]

    service, server, task = asyncio.run_coroutine_threadsafe(start(), loop).result(60)
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}"
    finally:
        asyncio.run_coroutine_threadsafe(stop(service, server, task), loop).result(30)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        with contextlib.suppress(OSError):
            sock.close()


def test_status_cycle_and_bring_to_execute_send_the_token(closed_cell: str) -> None:
    client = CellClient(closed_cell, token=TOKEN)
    assert httpx.get(closed_cell + "/status").status_code == 401  # reads are closed indeed
    assert client.status()["state"]
    assert client.bring_to_execute() == "EXECUTE"
    started = client.start_cycle("side-window", "C-1", wait=False)
    assert client.cycle(started["cycle_id"])["id"] == started["cycle_id"]


def test_cellctl_status_with_a_wrong_token_names_where_the_token_comes_from(
    closed_cell: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("CELLCTL_TOKEN", raising=False)
    assert main(["status", "--config", str(SIM), "--url", closed_cell, "--token", "not-this-cells"]) == 1
    err = capsys.readouterr().err
    assert "$CELLCTL_TOKEN" in err and "--token" in err and "refused" in err, err
    assert "needs a bearer token" not in err
    assert main(["status", "--config", str(SIM), "--url", closed_cell]) == 1
    assert "no token given" in capsys.readouterr().err
    assert main(["status", "--config", str(SIM), "--url", closed_cell, "--token", TOKEN]) == 0


def test_a_malformed_url_is_one_line_naming_url(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["status", "--config", str(SIM), "--url", "http://127.0.0.1:19x"])
    err = capsys.readouterr().err
    assert rc == 1 and "--url" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err


def test_an_answer_that_is_not_json_is_a_service_error(closed_cell: str) -> None:
    client = CellClient(closed_cell, token=TOKEN)
    with pytest.raises(ServiceError, match="not JSON"):
        client._call("GET", "/")  # the dashboard page: HTML with 200, as a proxy's login page would be
