"""Issue 15, bad input: ids past SQLite's 64-bit range are refused with 422 (they answered 500), and
every 422 carries the error body the OpenAPI document declares."""

from __future__ import annotations

from pathlib import Path

from service_test_support import AUTH, api_client, running_service, sim_config

from cellctl.api.schemas import SQLITE_INT_MAX, ErrorBody

# (method, path with {id} for the bounded id, the field's name in the 422, answer at the largest id)
ID_ROUTES = [
    ("GET", "/cycles/{id}", "cycle_id", 404),
    ("GET", "/cycles/{id}/images/corner.png", "cycle_id", 404),
    ("GET", "/cycles?before_id={id}", "before_id", 200),
    ("GET", "/dashboard/thumbs/{id}/corner.png", "cycle_id", 404),
    ("GET", "/jobs/{id}", "job_id", 404),
    ("GET", "/jobs/{id}/image", "job_id", 404),
    ("POST", "/jobs/{id}/cancel", "job_id", 404),
    ("POST", "/jobs/{id}/prompts/1", "job_id", 404),
    ("POST", "/jobs/1/prompts/{id}", "prompt_id", 404),
]


async def test_ids_outside_the_stores_range_are_refused_naming_the_field(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        for method, template, field, at_max in ID_ROUTES:
            body = {"action": "confirm"} if "/prompts/" in template else None
            for value, expected in ((2**63, 422), (2**64 + 5, 422), (0, 422), (SQLITE_INT_MAX, at_max)):
                r = await client.request(method, template.format(id=value), json=body, headers=AUTH)
                assert r.status_code == expected, (method, template, value, r.text)
                if expected == 422:
                    err = ErrorBody.model_validate(r.json())
                    assert [e.field for e in err.errors] == [field] and field in err.detail, r.text


async def test_every_422_is_the_error_body_the_document_declares(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        doc = (await client.get("/openapi.json")).json()
        assert "HTTPValidationError" not in doc["components"]["schemas"]
        for path, ops in doc["paths"].items():
            for method, op in ops.items():
                for code, response in op["responses"].items():
                    if code.startswith("4"):
                        schema = response["content"]["application/json"]["schema"]
                        assert schema == {"$ref": "#/components/schemas/ErrorBody"}, (method, path, code)
        assert doc["components"]["schemas"]["ErrorBody"]["properties"]["detail"]["type"] == "string"
        # A validation error (FastAPI's) and a refusal raised by a route (HTTPException) alike.
        bad = await client.get("/cycles", params={"limit": 0, "state": "lost"})
        body = {"recipe": "rear-door", "part_id": "P"}
        refused = await client.post("/cycle", json=body, headers={**AUTH, "Idempotency-Key": "k"})
        for r in (bad, refused):
            assert r.status_code == 422
            err = ErrorBody.model_validate(r.json())
            assert isinstance(r.json()["detail"], str) and err.detail
        assert sorted(e.field for e in ErrorBody.model_validate(bad.json()).errors) == ["limit", "state"]
