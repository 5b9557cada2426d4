"""Issue 17, the API's contract: every JSON answer has its schema in the OpenAPI document, the read
guard covers every route but the open ones, and /metrics is Prometheus text an independent parser
reads at full precision."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any
from unittest import mock

from prometheus_client import CONTENT_TYPE_LATEST
from prometheus_client.parser import text_string_to_metric_families
from service_test_support import AUTH, api_client, running_service, sim_config

from cellctl.api.app import create_app
from cellctl.store import CycleState

NOT_JSON = {
    ("get", "/events"): "text/event-stream",
    ("get", "/metrics"): "text/plain",
    ("get", "/cycles/{cycle_id}/images/{name}"): "image/png",
    ("get", "/jobs/{job_id}/image"): "image/png",
    ("get", "/dashboard/thumbs/{cycle_id}/{name}"): "image/png",
}
"""The routes whose answer is not JSON, and what it is."""

OPEN_ROUTES = {("get", "/health"), ("get", "/health/live")}
"""In the OpenAPI document, the only routes that answer an anonymous caller when reads are closed (the page at / is not in it)."""


def _document() -> dict[str, Any]:
    config = sim_config(plc={"enabled": False})
    return create_app(mock.MagicMock(name="orchestrator"), config.api, mock.MagicMock(name="jobs")).openapi()


def _resolve(schema: dict[str, Any], doc: dict[str, Any]) -> dict[str, Any]:
    ref = schema.get("$ref")
    return doc["components"]["schemas"][ref.rsplit("/", 1)[1]] if ref else schema


def _names_its_fields(schema: dict[str, Any], doc: dict[str, Any]) -> bool:
    """A model (or a list of one): a schema with properties, not ``{}`` or a bare object."""
    s = _resolve(schema, doc)
    if s.get("type") == "array":
        s = _resolve(s.get("items", {}), doc)
    return bool(s.get("properties"))


def test_every_json_answer_has_its_schema_in_the_openapi_document() -> None:
    doc = _document()
    seen = set()
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            seen.add((method, path))
            success = {code: r for code, r in op["responses"].items() if code.startswith("2")}
            assert success, (method, path)
            for code, response in success.items():
                content = response.get("content", {})
                if (method, path) in NOT_JSON:
                    assert list(content) == [NOT_JSON[method, path]], (method, path, code)
                    continue
                assert list(content) == ["application/json"], (method, path, code)
                schema = content["application/json"].get("schema", {})
                assert schema != {} and _names_its_fields(schema, doc), (method, path, code, schema)
    assert set(NOT_JSON) <= seen


async def test_closed_reads_leave_only_health_and_the_page_open(tmp_path: Path) -> None:
    doc = _document()
    config = sim_config(plc={"enabled": False}, api={"open_reads": False})
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        assert (await client.get("/")).status_code == 200
        for path, ops in doc["paths"].items():
            url = path.replace("{cycle_id}", "1").replace("{job_id}", "1").replace("{prompt_id}", "1")
            url = url.replace("{name}", "start").replace("{uid}", "x")
            for method in ops:
                r = await client.request(method.upper(), url)
                if (method, path) in OPEN_ROUTES:
                    assert r.status_code == 200, (method, path)
                    continue
                assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer", (method, path, r.status_code)
                assert "Bearer" in r.json()["detail"], (method, path)


async def test_metrics_parse_as_prometheus_text_at_full_precision(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        before = time.time()
        r = await client.get("/metrics", headers=AUTH)
        after = time.time()
    assert r.status_code == 200 and r.headers["content-type"] == CONTENT_TYPE_LATEST
    families = {f.name: f for f in text_string_to_metric_families(r.text)}
    cell_gauges = {
        "cellctl_packml_state", "cellctl_unit_mode", "cellctl_cycles", "cellctl_alarms_active",
        "cellctl_device_up", "cellctl_device_heartbeat_age_seconds", "cellctl_scrape_timestamp_seconds",
        "cellctl_build_info",
    }  # fmt: skip
    histogram = {"cellctl_cycle_time_seconds", "cellctl_cycle_time_seconds_created"}  # the text format's _created as a gauge
    assert {n for n in families if n.startswith("cellctl_")} == cell_gauges | histogram
    assert all(families[n].type == "gauge" for n in cell_gauges)
    assert families["cellctl_cycle_time_seconds"].type == "histogram"
    assert {n.split("_")[0] for n in families} == {"cellctl", "process", "python"}  # the process collectors, nothing else
    assert [s.value for s in families["cellctl_packml_state"].samples] == [9.0]  # Aborted: the service starts there
    assert {s.labels["state"]: s.value for s in families["cellctl_cycles"].samples} == {s.value: 0.0 for s in CycleState}
    assert {s.labels["device"] for s in families["cellctl_device_up"].samples} == {"laser", "camera", "robot"}
    # A Unix time needs 10 significant digits for the second (6, as '%g' wrote them, are off by up to 5000 s).
    (stamp,) = families["cellctl_scrape_timestamp_seconds"].samples
    assert before <= stamp.value <= after, (before, stamp.value, after)
