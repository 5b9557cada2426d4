"""POST /cycle's part_id and car_id: what the store refuses (blank, control characters) is a 422 naming the field and
what is allowed (it answered 500), the OpenAPI document says the same, and a blank car_id is no car_id (null)."""

from __future__ import annotations

from pathlib import Path
from unittest import mock

import jsonschema_rs
import pytest
from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

from cellctl.api.app import create_app
from cellctl.api.schemas import ErrorBody
from cellctl.store import CycleRequest
from cellctl.store.records import NAME_ALLOWED, TEXT_ALLOWED

pytestmark = pytest.mark.timeout(180)
GOOD = {"recipe": "side-window", "part_id": "G-2026-000815", "car_id": "CB-30117"}
# (field, bad value, what the 422 says about it); U+00A0 and U+3000 are white space too, as str.strip() has it
BAD = [
    ("part_id", "", "must not be empty or only white space"),
    ("part_id", "   ", "must not be empty or only white space"),
    ("part_id", "\u00a0\u3000", "must not be empty or only white space"),
    ("part_id", "P\x01-1", "contains control characters"),
    ("part_id", "P-1\n", "contains control characters"),
    ("part_id", "\t", "contains control characters"),
    ("car_id", "CB\t30117", "contains control characters"),
    ("car_id", "\x1f", "contains control characters"),
]


async def test_a_part_or_car_id_the_store_refuses_is_a_422_naming_the_field(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        for k, (field, value, said) in enumerate(BAD):
            with pytest.raises(ValueError, match=f"{field} {said}"):  # the store's own guard refuses it too
                CycleRequest(**(GOOD | {field: value}))
            r = await client.post("/cycle", json=GOOD | {field: value}, headers={**AUTH, "Idempotency-Key": f"bad-{k}"})
            assert r.status_code == 422, (field, value, r.status_code, r.text)
            err = ErrorBody.model_validate(r.json())
            assert [e.field for e in err.errors] == [field], r.text
            allowed = NAME_ALLOWED if field == "part_id" else TEXT_ALLOWED
            assert err.detail == f"body field '{field}': {said}; use {allowed}", r.text
        assert await service.store.cycles(limit=10) == []


def test_the_openapi_document_says_what_the_ids_may_hold() -> None:
    config = sim_config(plc={"enabled": False})
    doc = create_app(mock.MagicMock(name="orchestrator"), config.api, mock.MagicMock(name="jobs")).openapi()
    body = doc["components"]["schemas"]["CycleRequestBody"]
    assert NAME_ALLOWED in body["properties"]["part_id"]["description"]
    assert TEXT_ALLOWED in body["properties"]["car_id"]["description"]
    assert "only white space: not known (recorded as null)" in body["properties"]["car_id"]["description"]
    validator = jsonschema_rs.Draft202012Validator(body)  # a client reading the document (Rust regex): an independent peer
    for field, value, _ in BAD:
        assert not validator.is_valid(GOOD | {field: value}), (field, value)
    for good in (GOOD, GOOD | {"car_id": None}, GOOD | {"car_id": ""}, GOOD | {"car_id": "  "}, GOOD | {"part_id": " P 1 "}):
        assert validator.is_valid(good), good


async def test_a_blank_car_id_is_no_car_id(tmp_path: Path) -> None:
    """car_id is optional (null or left out); empty or white space says the same, as the OPC UA StartCycle has it."""
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        await to_execute(client)
        key = {**AUTH, "Idempotency-Key": "blank-car"}
        r = await client.post("/cycle?wait=true&timeout_s=60", json=GOOD | {"car_id": " "}, headers=key)
        assert r.status_code == 200 and r.json()["car_id"] is None, r.text
        cycle_id = r.json()["id"]
        assert (await service.store.cycle(cycle_id)).request.car_id is None
        for same in ({"car_id": None}, {"car_id": ""}, {"car_id": "\u3000"}):  # the same request under the same key
            body = {k: v for k, v in (GOOD | same).items() if v is not None}
            again = await client.post("/cycle", json=body, headers=key)
            assert again.status_code == 202 and again.json()["cycle_id"] == cycle_id, again.text
            assert again.json()["created"] is False
