"""POST /jobs/plan (open to readers): options past their range get a 422 naming the field and the range,
and a large allowed plan is worked out off the event loop, so GET /status from another client is answered meanwhile."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_test_support import running_service, sim_config

from cellctl.api.app import create_app
from cellctl.commissioning import plans

GATE_S = 30.0  # only breaks a deadlock: a plan on the event loop would hold /status until the gate gives up


def _config() -> Any:
    return sim_config(calibration={"source": "set", "auto_calibrate_in_sim": False}, plc={"enabled": False})


@pytest.mark.parametrize(
    ("procedure", "options", "field", "range_text"),
    [
        ("laser", {"poses": 100_000}, "options.poses", "to 5000"),
        ("laser", {"poses": 3}, "options.poses", "to 5000"),
        ("camera", {"views": 5000}, "options.views", "from 3 to 200"),
        ("hand_eye", {"views": 2}, "options.views", "from 3 to 200"),
    ],
)
async def test_an_option_past_its_range_is_a_422_naming_the_field_and_range(
    tmp_path: Path, procedure: str, options: dict[str, Any], field: str, range_text: str
) -> None:
    async with running_service(tmp_path, _config()) as service:
        app = create_app(service.orchestrator, service.config.api, service.jobs)
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://cell") as client:
            r = await client.post("/jobs/plan", json={"procedure": procedure, "options": options})
            assert r.status_code == 422, r.text
            detail = r.json()["detail"]
            assert isinstance(detail, str) and detail.startswith(f"{field}:") and range_text in detail, detail


@pytest.mark.parametrize(("gate", "procedure", "options", "poses"), [
    ("plan_laser_poses", "laser", {"poses": 1500}, 1500),  # the planning
    ("pose_row", "camera", {"views": 200}, 150),  # the plan's summary (a row per pose, the rotation spread) is CPU too
], ids=["planning", "summary"])  # fmt: skip
async def test_status_is_answered_while_a_large_plan_is_worked_out(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, gate: str, procedure: str, options: dict[str, int], poses: int
) -> None:
    started, release = threading.Event(), threading.Event()
    real = getattr(plans, gate)
    order: list[str] = []

    def gated(*args: Any, **kwargs: Any) -> Any:
        if not started.is_set():
            started.set()
            if not release.wait(GATE_S):
                order.append("gate gave up")
        return real(*args, **kwargs)

    monkeypatch.setattr(plans, gate, gated)
    async with running_service(tmp_path, _config()) as service:
        app = create_app(service.orchestrator, service.config.api, service.jobs)
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://cell") as planner, \
                httpx.AsyncClient(transport=transport, base_url="http://cell") as reader:  # fmt: skip

            async def plan() -> httpx.Response:
                r = await planner.post("/jobs/plan?poses=true", json={"procedure": procedure, "options": options})
                order.append("plan answered")
                return r

            planning = asyncio.create_task(plan())
            assert await asyncio.to_thread(started.wait, GATE_S), "the plan never started"
            status = await reader.get("/status")
            order.append("status answered")
            release.set()
            r = await planning
    assert status.status_code == 200 and "state" in status.json()
    assert r.status_code == 200, r.text
    assert r.json()["poses"] == len(r.json()["pose_list"]) >= poses
    assert order == ["status answered", "plan answered"]


async def test_plans_are_worked_out_one_at_a_time_a_second_reader_gets_429(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A reader cannot start plan after plan: each would hold a worker thread the cycle's vision needs for seconds."""
    started, release = threading.Event(), threading.Event()
    real = plans.plan_laser_poses

    def gated(*args: Any, **kwargs: Any) -> Any:
        started.set()
        release.wait(GATE_S)
        return real(*args, **kwargs)

    monkeypatch.setattr(plans, "plan_laser_poses", gated)
    async with running_service(tmp_path, _config()) as service:
        app = create_app(service.orchestrator, service.config.api, service.jobs)
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://cell") as first, \
                httpx.AsyncClient(transport=transport, base_url="http://cell") as second:  # fmt: skip
            planning = asyncio.create_task(first.post("/jobs/plan", json={"procedure": "laser", "options": {"poses": 600}}))
            assert await asyncio.to_thread(started.wait, GATE_S), "the plan never started"
            busy = await second.post("/jobs/plan", json={"procedure": "camera", "options": {"views": 8}})
            bad = await second.post("/jobs/plan", json={"procedure": "camera", "options": {"views": 900}})
            release.set()
            r = await planning
            after = await second.post("/jobs/plan", json={"procedure": "camera", "options": {"views": 8}})
    assert busy.status_code == 429, busy.text
    assert "a plan of laser is being worked out" in busy.json()["detail"] and busy.headers["Retry-After"] == "1"
    assert bad.status_code == 422 and bad.json()["detail"].startswith("options.views:")  # a bad option is still named
    assert r.status_code == 200 and r.json()["poses"] == 600
    assert after.status_code == 200 and after.json()["poses"] == 8
