"""A query parameter a route does not declare is refused with 422 naming it (a misspelled filter never returns
unfiltered data), on every route with query parameters; the dashboard's own requests send only declared ones."""

from __future__ import annotations

import re
from pathlib import Path

from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

STATIC = Path(__file__).resolve().parents[2] / "src" / "cellctl" / "api" / "static"

# Every query the dashboard builds (static/*.js), with example values.
DASHBOARD_QUERIES = [
    "/alarms?history=true",
    "/jobs?limit=20",
    "/cycles?limit=200&state=failed",
    "/dashboard/cycles?limit=60",
    "/dashboard/shifts?tz_offset_min=60&count=3&starts=06%3A00%2C18%3A00",
    "/dashboard/shifts?tz=Europe%2FBerlin&count=3&starts=06%3A00%2C18%3A00",
    "/dashboard/thumbs/1/x.png?width=256",
    "/jobs/1/image?width=640&frame=3",
]


async def test_a_misspelled_parts_filter_is_refused_naming_it_and_the_known_ones(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as svc, api_client(svc) as c:
        await to_execute(c)
        r = await c.post("/cycle?wait=true", json={"recipe": "side-window", "part_id": "G-1", "car_id": "CAR-1"},
                         headers={**AUTH, "Idempotency-Key": "g1"})  # fmt: skip
        assert r.status_code == 200, r.text
        assert len((await c.get("/parts", params={"car_id": "CAR-9"})).json()["installs"]) == 0
        r = await c.get("/parts", params={"car": "CAR-9"})
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert "'car'" in detail and "car_id" in detail and "part_id" in detail, detail
        assert (await c.get("/cycles", params={"status": "failed"})).status_code == 422


async def test_every_route_with_query_parameters_refuses_an_unknown_one(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as svc, api_client(svc) as c:
        paths = (await c.get("/openapi.json")).json()["paths"]
        checked = []
        for template, ops in paths.items():
            for method, op in ops.items():
                declared = {p["name"] for p in op.get("parameters", []) if p["in"] == "query"}
                if not declared:
                    continue
                path = re.sub(r"\{[^}]+\}", "1", template)
                r = await c.request(method.upper(), path, params={"zz_typo": "1"}, headers={**AUTH, "Idempotency-Key": "q"})
                assert r.status_code == 422, (method, template, r.status_code)
                assert "zz_typo" in r.json()["detail"] and all(n in r.json()["detail"] for n in declared), r.text
                checked.append((method, template))
        assert ("get", "/parts") in checked and ("get", "/cycles") in checked and ("get", "/dashboard/shifts") in checked


async def test_the_dashboards_own_queries_are_all_declared(tmp_path: Path) -> None:
    in_js = {m for f in STATIC.glob("*.js") for m in re.findall(r"[?&]([a-z_]+)=", f.read_text())}
    listed = {name for q in DASHBOARD_QUERIES for name in re.findall(r"[?&]([a-z_]+)=", q)}
    assert in_js <= listed, f"the dashboard sends {sorted(in_js - listed)}: add them to DASHBOARD_QUERIES"
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as svc, api_client(svc) as c:
        for url in DASHBOARD_QUERIES:
            r = await c.get(url)
            assert r.status_code in (200, 404), (url, r.status_code, r.text)
