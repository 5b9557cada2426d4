"""``GET /parts`` takes ``since`` and ``until`` in ISO 8601 (as documented) only: a number, which pydantic
would read as Unix seconds (or milliseconds above 2e10), is a 422 naming the field and the format."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest
from service_test_support import api_client, running_service, sim_config

from cellctl.api.routes_parts import TIME_FORMAT


@pytest.fixture()
async def client(tmp_path: Path) -> AsyncIterator[httpx.AsyncClient]:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as svc, api_client(svc) as c:
        yield c


async def test_a_number_is_not_a_time_for_since_or_until(client: httpx.AsyncClient) -> None:
    for field in ("since", "until"):
        for number in ("99999999999", "1700000000", "1.7e9", "-1", "0"):
            r = await client.get("/parts", params={field: number})
            assert r.status_code == 422, (field, number, r.text)
            errors = r.json()["errors"]
            assert [(e["in"], e["field"]) for e in errors] == [("query", field)], errors
            assert "is a number, not a time" in errors[0]["message"] and TIME_FORMAT in errors[0]["message"], errors
            assert f"query field '{field}'" in r.json()["detail"]


async def test_iso_8601_times_still_filter(client: httpx.AsyncClient) -> None:
    window = {"since": "2025-03-01T06:00:00+01:00", "until": "2025-03-02T05:00:00Z"}
    r = await client.get("/parts", params=window)
    assert r.status_code == 200, r.text
    assert (await client.get("/parts", params={"since": "2025-03-01T06:00:00"})).status_code == 422  # no timezone
