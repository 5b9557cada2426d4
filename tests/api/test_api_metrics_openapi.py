"""Issue 20, /metrics and the OpenAPI document: the cycle-time histogram, build info and process metrics
as a Prometheus parser reads them; the bearer scheme declared, and on each route that takes a token."""

from __future__ import annotations

from pathlib import Path
from unittest import mock

import pytest
from prometheus_client.parser import text_string_to_metric_families
from service_test_support import (
    AUTH,
    api_client,
    running_service,
    sim_config,
    to_execute,
)

import cellctl
from cellctl.api.app import create_app
from cellctl.api.auth import SECURITY_SCHEME
from cellctl.api.metrics import CYCLE_TIME_BUCKETS_S

pytestmark = pytest.mark.timeout(120)


async def test_metrics_have_the_cycle_time_histogram_build_info_and_process_metrics(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        before = {f.name: f for f in text_string_to_metric_families((await client.get("/metrics")).text)}
        assert before["cellctl_cycle_time_seconds"].type == "histogram"
        await to_execute(client)
        for n in range(2):
            r = await client.post("/cycle?wait=true&timeout_s=60", json={"recipe": "side-window", "part_id": f"M-{n}"},
                                  headers={**AUTH, "Idempotency-Key": f"metrics-{n}"})  # fmt: skip
            assert r.status_code == 200 and r.json()["state"] == "done", r.text
        text = (await client.get("/metrics")).text
        families = {f.name: f for f in text_string_to_metric_families(text)}

        hist = families["cellctl_cycle_time_seconds"]
        samples = {(s.name, s.labels.get("outcome"), s.labels.get("le")): s.value for s in hist.samples}
        assert samples[("cellctl_cycle_time_seconds_count", "done", None)] == 2
        assert samples[("cellctl_cycle_time_seconds_count", "failed", None)] == 0
        assert samples[("cellctl_cycle_time_seconds_bucket", "done", "+Inf")] == 2
        les = sorted(float(le) for (name, outcome, le) in samples if name.endswith("_bucket") and outcome == "done" and le != "+Inf")
        assert les == list(CYCLE_TIME_BUCKETS_S) and les[0] == 0.5 and les[-1] == 60.0
        records = await service.store.cycles(limit=5)
        recorded = sum(float(r.result["cycle_time_s"]) for r in records)  # type: ignore[index]
        assert samples[("cellctl_cycle_time_seconds_sum", "done", None)] == pytest.approx(recorded)
        again = {f.name: f for f in text_string_to_metric_families((await client.get("/metrics")).text)}
        counts = [s.value for s in again["cellctl_cycle_time_seconds"].samples if s.name.endswith("_count") and s.labels["outcome"] == "done"]
        assert counts == [2]  # a second scrape counts no cycle twice

        build = families["cellctl_build_info"].samples
        assert len(build) == 1 and build[0].value == 1 and build[0].labels["version"] == cellctl.__version__
        assert families["process_resident_memory_bytes"].samples[0].value > 10e6
        assert families["process_cpu_seconds"].samples[0].value > 0
        assert "process_open_fds" in families and "python_info" in families
        assert families["cellctl_packml_state"].samples[0].value == 6  # the cell's own gauges are still there


@pytest.mark.parametrize("open_reads", [True, False])
def test_the_openapi_document_declares_the_bearer_scheme_on_each_guarded_route(open_reads: bool) -> None:
    config = sim_config(plc={"enabled": False}, api={"open_reads": open_reads})
    doc = create_app(mock.MagicMock(name="orchestrator"), config.api, mock.MagicMock(name="jobs")).openapi()
    assert doc["components"]["securitySchemes"][SECURITY_SCHEME] == {
        "type": "http", "scheme": "bearer", "description": mock.ANY}  # fmt: skip
    required, optional = [{SECURITY_SCHEME: []}], [{}, {SECURITY_SCHEME: []}]
    ops = {(m, p): op for p, item in doc["paths"].items() for m, op in item.items()}
    for (method, path), op in ops.items():
        if path in ("/health/live",):
            assert "security" not in op, path
        elif path == "/health":
            assert op["security"] == optional  # open; with closed reads the token shows the details
        elif method != "get" and path != "/jobs/plan":
            assert op["security"] == required, (method, path)
        else:
            assert op["security"] == (optional if open_reads else required), (method, path)


async def test_docs_offer_authorize_for_the_page_only(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        doc = (await client.get("/openapi.json")).json()
        assert doc["paths"]["/commands/{name}"]["post"]["security"] == [{SECURITY_SCHEME: []}]
        page = (await client.get("/docs")).text
        assert "persistAuthorization" not in page  # a shared HMI PC keeps no token after the tab (review r4 D3)
