"""The REST API fuzzed with schemathesis: no 5xx, and every answer inside its OpenAPI schema.

The real simulated cell service (the composition root of ``cellctl serve``, the twin's true
calibrations, no PLC server) runs in-process behind schemathesis's ASGI transport: no socket.
The ASGI app below starts the service in its lifespan, so the service's tasks and the requests
share the one event loop the transport runs them on. Every route of the OpenAPI document is its
own test, fuzzed with the operator's bearer token: schemathesis's coverage phase (boundary and
invalid values of every parameter and body field, unexpected methods), then
``EXAMPLES_PER_ROUTE`` generated cases (valid and invalid), deterministic. Checked on every
answer: no 5xx, a documented status code, content type, headers and body schema.

Left out or held back, and why:

- ``GET /events`` is not fuzzed: the event stream never ends on its own (and is ``text/event-stream``).
- ``POST /cycle`` and ``POST /jobs`` start work: the cell is put back in Aborted before each of
  their cases (the fuzzed ``POST /commands/{name}`` wanders the state machine), where both are
  refused with 409 after their input is checked, so no cycle or job moves the twin.

About 20 s on a 2-core machine (1,500 requests).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from unittest import mock

import pytest
import schemathesis
from schemathesis.python.asgi import get_client, shutdown_lifespans
from service_test_support import AUTH, TOKEN, sim_config

from cellctl.api.app import create_app
from cellctl.service import build_service
from cellctl.service.compose import Service

SEED = 15
EXAMPLES_PER_ROUTE = 50
STARTS_WORK = {("POST", "/cycle"), ("POST", "/jobs")}
SETTLE_S = 5.0

CONFIG = schemathesis.Config.from_dict({
    "seed": SEED,
    "headers": {"Authorization": f"Bearer {TOKEN}"},
    "generation": {"max-examples": EXAMPLES_PER_ROUTE, "database": "none", "deterministic": True},
    "phases": {"stateful": {"enabled": False}},
    "checks": {
        "enabled": False,
        "not_a_server_error": {"enabled": True},
        "status_code_conformance": {"enabled": True},
        "content_type_conformance": {"enabled": True},
        "response_schema_conformance": {"enabled": True},
        "response_headers_conformance": {"enabled": True},
    },
})  # fmt: skip


class CellService:
    """An ASGI app whose lifespan builds and starts the simulated cell service and stops it."""

    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        self.service: Service | None = None
        self.app: Any = None

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] != "lifespan":
            await self.app(scope, receive, send)
            return
        while True:
            message = await receive()
            if message["type"] == "lifespan.startup":
                try:
                    config = sim_config(plc={"enabled": False})
                    self.service = await build_service(config, workdir=self.workdir)
                    await self.service.start()
                    self.app = create_app(self.service.orchestrator, config.api, self.service.jobs)
                except Exception as err:  # noqa: BLE001 (any failure to start is reported to the transport, which raises it)
                    await send({"type": "lifespan.startup.failed", "message": repr(err)})
                    return
                await send({"type": "lifespan.startup.complete"})
            elif message["type"] == "lifespan.shutdown":
                if self.service is not None:
                    await self.service.stop()
                await send({"type": "lifespan.shutdown.complete"})
                return


def _document() -> dict[str, Any]:
    """The OpenAPI document, from the routes alone (a stand-in cell: nothing is called while it is made)."""
    config = sim_config(plc={"enabled": False})
    return create_app(mock.MagicMock(name="orchestrator"), config.api, mock.MagicMock(name="jobs")).openapi()


# Collected from the document so that every route is its own test; the fixture below checks that the
# running app serves this very document.
DOCUMENT = _document()
schema = schemathesis.openapi.from_dict(DOCUMENT, config=CONFIG).exclude(path="/events")


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[CellService]:
    app = CellService(tmp_path_factory.mktemp("fuzz"))
    try:
        with get_client(app) as client:  # starts the lifespan: the service runs until shutdown_lifespans()
            assert client.get("/openapi.json").json() == DOCUMENT
        yield app
    finally:
        shutdown_lifespans()


def put_back_in_aborted(app: CellService) -> None:
    """Abort (refused, and harmless, if already Aborted) and wait out Aborting."""
    with get_client(app) as client:
        client.post("/commands/abort", headers=AUTH)
        deadline = time.monotonic() + SETTLE_S
        while (state := client.get("/status", headers=AUTH).json()["state"]) != "ABORTED":
            assert time.monotonic() < deadline, f"the cell did not return to Aborted (it is {state})"
            time.sleep(0.01)


@schema.parametrize()
def test_every_route_answers_inside_its_schema(case: Any, cell: CellService) -> None:
    if (case.method.upper(), case.path) in STARTS_WORK:
        put_back_in_aborted(cell)
    case.call_and_validate(app=cell, headers=AUTH)
