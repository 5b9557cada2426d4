"""A body that is not JSON is reported as such, with where (not as a field named by the character offset)."""

from __future__ import annotations

import json
import re
from pathlib import Path

from service_test_support import AUTH, api_client, running_service, sim_config

BAD = b'{"recipe": "side-window", "part_id": "P-1",}'


async def test_a_trailing_comma_is_not_valid_json_at_its_character(tmp_path: Path) -> None:
    try:
        json.loads(BAD)
    except json.JSONDecodeError as err:  # the standard library says where the text stops being JSON
        where = err.pos
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as svc, api_client(svc) as c:
        r = await c.post("/cycle", content=BAD, headers={**AUTH, "Idempotency-Key": "j", "Content-Type": "application/json"})
        assert r.status_code == 422
        detail = r.json()["detail"]
        assert not re.search(r"field '\d+'", detail), detail
        assert detail.startswith("body: not valid JSON at character"), detail
        assert str(where) in detail or str(where + 1) in detail, (where, detail)
        assert r.json()["errors"][0]["type"] == "json_invalid"
