"""/docs keeps the bearer token in the page only: Swagger UI stores it in the browser's localStorage
(where it outlives the browser on a shared HMI PC) only when persistAuthorization is set."""

from __future__ import annotations

from pathlib import Path

from service_test_support import api_client, running_service, sim_config


async def test_docs_do_not_persist_the_token(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        r = await client.get("/docs")
        assert r.status_code == 200 and "SwaggerUIBundle(" in r.text
        assert "persistAuthorization" not in r.text, "the /docs page asks Swagger UI to store the token in localStorage"
