"""A 401 says which of the two it is: no token was sent, or the token sent is not one of [api].tokens."""

from __future__ import annotations

from pathlib import Path

from service_test_support import api_client, running_service, sim_config

WRONG = {"Authorization": "Bearer not-a-token-of-this-cell"}


async def test_no_token_and_a_wrong_token_get_different_details(tmp_path: Path) -> None:
    config = sim_config(plc={"enabled": False}, api={"open_reads": False})
    async with running_service(tmp_path, config) as svc, api_client(svc) as c:
        for method, path in (("POST", "/commands/stop"), ("GET", "/status"), ("GET", "/cycles")):
            none = await c.request(method, path)
            wrong = await c.request(method, path, headers=WRONG)
            assert none.status_code == wrong.status_code == 401, path
            assert "needs a bearer token" in none.json()["detail"], none.text
            assert "not one of [api].tokens" in wrong.json()["detail"], wrong.text
            assert "needs a bearer token" not in wrong.json()["detail"]
