"""The dashboard's thumbnail route declares in /openapi.json the 410 it answers for an image no longer on disk."""

from __future__ import annotations

from pathlib import Path

from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

from cellctl.api.schemas import ErrorBody


async def test_the_thumbnail_routes_410_is_declared_with_the_error_body(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as svc, api_client(svc) as c:
        await to_execute(c)
        rec = (await c.post("/cycle?wait=true", json={"recipe": "side-window", "part_id": "T-1"},
                            headers={**AUTH, "Idempotency-Key": "t1"})).json()  # fmt: skip
        ref = (await svc.orchestrator.store.cycle(rec["id"])).images[0]
        (svc.orchestrator.image_dir / ref.uri).unlink()
        r = await c.get(f"/dashboard/thumbs/{rec['id']}/{ref.name}")
        assert r.status_code == 410
        ErrorBody.model_validate(r.json())
        declared = (await c.get("/openapi.json")).json()["paths"]["/dashboard/thumbs/{cycle_id}/{name}"]["get"]["responses"]
        assert declared["410"]["content"]["application/json"]["schema"] == {"$ref": "#/components/schemas/ErrorBody"}
