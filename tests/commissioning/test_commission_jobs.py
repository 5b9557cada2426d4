"""Commissioning jobs in the running service: when they may run, prompts, cancel, Stop, reduced speed, refusals.

The service is the simulated cell's real composition (the LK-G and ABB drivers over their
protocol fakes, the twin behind them), driven over its REST API in-process.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_test_support import AUTH, api_client, running_service, sim_config, slow_moves

from cellctl.calibration.calibration_set import CalibrationStore
from cellctl.calibration.dataset import read_dataset
from cellctl.cell.tags import PackMLState
from cellctl.ports import MotionRequest

FINISHED = {"done", "refused", "failed", "cancelled", "interrupted"}


def _config(answers: str = "actions", time_scale: float = 0.001, **extra: dict[str, Any]) -> Any:
    sections: dict[str, dict[str, Any]] = {
        "calibration": {"source": "set", "auto_calibrate_in_sim": False},
        "sim": {"time_scale": time_scale},
        "sim.operator": {"answers": answers},
        "plc": {"enabled": False},
    }
    sections.update(extra)
    return sim_config(**sections)


async def _settle(client: httpx.AsyncClient) -> str:
    for _ in range(300):
        state = (await client.get("/status")).json()["state"]
        if not state.endswith("ING"):
            return state
        await asyncio.sleep(0.01)
    raise AssertionError("the cell stayed in an acting state")


async def _command(client: httpx.AsyncClient, name: str) -> str:
    r = await client.post(f"/commands/{name}", headers=AUTH)
    assert r.status_code == 200, r.text
    return await _settle(client)


async def _start(client: httpx.AsyncClient, procedure: str, **options: Any) -> dict[str, Any]:
    r = await client.post("/jobs", json={"procedure": procedure, "options": options}, headers=AUTH)
    assert r.status_code == 201, r.text
    return r.json()


async def _wait_prompt(client: httpx.AsyncClient, job_id: int, kind: str, timeout_s: float = 20.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = (await client.get(f"/jobs/{job_id}")).json()
        if job["prompt"] is not None and job["prompt"]["kind"] == kind:
            return job["prompt"]
        assert job["state"] not in FINISHED, job
        await asyncio.sleep(0.02)
    raise AssertionError(f"no {kind} prompt within {timeout_s} s")


async def _wait_done(client: httpx.AsyncClient, job_id: int, timeout_s: float = 60.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = (await client.get(f"/jobs/{job_id}")).json()
        if job["state"] in FINISHED:
            return job
        await asyncio.sleep(0.05)
    raise AssertionError(f"job {job_id} did not end within {timeout_s} s")


async def test_jobs_run_only_in_stopped_or_idle_one_at_a_time_and_start_waits_for_them(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        # The cell starts Aborted: no job, and the refusal says what to send.
        r = await client.post("/jobs", json={"procedure": "laser", "options": {"poses": 120}}, headers=AUTH)
        assert r.status_code == 409 and "ABORTED" in r.json()["detail"] and "Clear" in r.json()["detail"]
        assert await _command(client, "clear") == "STOPPED"
        # Bad options name the field and what it takes; unknown procedures list the known ones.
        r = await client.post("/jobs", json={"procedure": "laser", "options": {"views": 5}}, headers=AUTH)
        assert r.status_code == 422 and "options.views" in r.json()["detail"]
        r = await client.post("/jobs", json={"procedure": "laser", "options": {"poses": 3}}, headers=AUTH)
        assert r.status_code == 422 and "options.poses" in r.json()["detail"] and "100" in r.json()["detail"]
        r = await client.post("/jobs", json={"procedure": "gyro"}, headers=AUTH)
        assert r.status_code == 422 and "hand_eye" in r.json()["detail"]
        assert (await client.post("/jobs", json={"procedure": "laser"})).status_code == 401
        # Teaching needs the sensors calibrated first.
        r = await client.post("/jobs", json={"procedure": "teaching"}, headers=AUTH)
        assert r.status_code == 409 and "camera" in r.json()["detail"]
        job = await _start(client, "laser", poses=120)
        await _wait_prompt(client, job["id"], "confirm_start")
        # One job at a time; no Start (so no cycle) while it runs; /status shows it.
        r = await client.post("/jobs", json={"procedure": "camera"}, headers=AUTH)
        assert r.status_code == 409 and f"job {job['id']}" in r.json()["detail"]
        assert await _command(client, "reset") == "IDLE"
        r = await client.post("/commands/start", headers=AUTH)
        assert r.status_code == 409 and "commissioning job" in r.json()["detail"]
        st = (await client.get("/status")).json()
        assert st["job"]["id"] == job["id"] and st["job"]["prompt"] == "confirm_start"
        await client.post(f"/jobs/{job['id']}/cancel", headers=AUTH)
        assert (await client.post("/commands/start", headers=AUTH)).status_code == 200


async def test_a_prompt_waits_for_the_engineer_and_the_answer_is_audited(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        await _command(client, "clear")
        job = await _start(client, "laser", poses=120)
        prompt = await _wait_prompt(client, job["id"], "confirm_start")
        # The plan is shown before the first move: the poses, the robot time, the first pose.
        shown = (await client.get(f"/jobs/{job['id']}")).json()
        assert shown["plan"]["poses"] == 120 and shown["plan"]["estimated_robot_time_s"] > 0
        assert prompt["details"]["first_pose"]["position_mm"] == shown["plan"]["first_pose"]["position_mm"]
        assert shown["progress"] in (None, {})  # nothing moved yet
        # A value is refused for a prompt that asks none; a wrong prompt id is not found.
        r = await client.post(f"/jobs/{job['id']}/prompts/{prompt['id']}", json={"action": "value", "value": 3.0}, headers=AUTH)
        assert r.status_code == 422 and "asks for no value" in r.json()["detail"]
        r = await client.post(f"/jobs/{job['id']}/prompts/{prompt['id'] + 99}", json={"action": "confirm"}, headers=AUTH)
        assert r.status_code == 404
        r = await client.post(f"/jobs/{job['id']}/prompts/{prompt['id']}", json={"action": "confirm"}, headers=AUTH)
        assert r.status_code == 200
        done = await _wait_done(client, job["id"])
        assert done["state"] == "done" and done["version_after"] == 1, done
        assert done["result"]["quality"]["readings_used"] >= 110
        entries = await service.store.audit_entries(limit=500)
        answered = [e for e in entries if e.action == "job.prompt" and e.params["kind"] == "confirm_start"]
        assert len(answered) == 1 and answered[0].actor == "operator"
        hands_on = [e for e in entries if e.action == "job.prompt" and e.params["kind"] == "car_body_in_place"]
        assert hands_on and hands_on[0].actor == "simulated operator"
        # The dataset says where it came from.
        ds = read_dataset(done["dataset"], "laser_plane")
        assert ds.manifest["source"]["mode"] == "sim" and ds.manifest["job_id"] == job["id"]
        assert ds.manifest["source"]["laser"]["dialect"] == "LK-G5001"


async def _laser_job_under_way(client: httpx.AsyncClient, done: int = 3) -> dict[str, Any]:
    """A 200-pose laser job, once ``done`` poses are read (call slow_moves first: it must not end meanwhile)."""
    job = await _start(client, "laser", poses=200)
    while ((await client.get(f"/jobs/{job['id']}")).json().get("progress") or {}).get("done", 0) < done:
        await asyncio.sleep(0.02)
    return job


async def test_cancel_stops_the_robot_at_once_keeps_the_partial_dataset_and_the_set(tmp_path: Path) -> None:
    cfg = _config(answers="all")
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        await _command(client, "clear")
        first = await _start(client, "laser", poses=120)
        assert (await _wait_done(client, first["id"], timeout_s=120))["state"] == "done"
        store = CalibrationStore(service.jobs.calibration_store.root)
        version = store.current().version
        slow_moves(service, 200.0)  # 0.2 of real time per simulated second
        job = await _laser_job_under_way(client, done=5)
        robot = service.orchestrator.devices.robot
        t0 = time.monotonic()
        r = await client.post(f"/jobs/{job['id']}/cancel", headers=AUTH)
        took = time.monotonic() - t0
        assert r.status_code == 200 and r.json()["state"] == "cancelled", r.text
        assert not (await robot.state(timeout_s=2.0)).moving
        assert took < cfg.devices.call_timeout_s
        rec = r.json()
        assert "cancelled by operator" in rec["error"]
        partial = read_dataset(rec["dataset"], "laser_plane", allow_partial=True)
        assert partial.manifest["partial"] is True and "cancelled by operator" in partial.manifest["ended"]
        assert 5 <= len(partial.manifest["readings"]) < 200
        assert store.current().version == version  # the set in use is unchanged
        entries = await service.store.audit_entries(limit=500)
        assert any(e.action == "job.cancel" and e.actor == "operator" for e in entries)


async def test_a_cancel_whose_task_cancellation_is_lost_still_ends_the_job_at_its_next_pose(tmp_path: Path) -> None:
    # asyncio.wait_for (Python 3.11) can swallow a cancellation that lands as the awaited driver call
    # completes, and a stop that lands between two moves interrupts none: here the job's task is hidden
    # from the cancel and the robot's stop does nothing, the worst such case.
    async with running_service(tmp_path, _config(answers="all")) as service, api_client(service) as client:
        slow_moves(service, 200.0)
        await _command(client, "clear")
        job = await _laser_job_under_way(client)
        service.jobs._running.task = None  # the cancel can neither cancel nor await it

        async def stop_between_moves(*, timeout_s: float) -> None:
            return None

        service.jobs.devices.robot.stop = stop_between_moves
        r = await client.post(f"/jobs/{job['id']}/cancel", headers=AUTH)
        assert r.status_code == 200, r.text
        done = await _wait_done(client, job["id"], timeout_s=10)
        assert done["state"] == "cancelled" and "cancelled by operator" in done["error"], done
        assert done["progress"]["done"] < 200


async def test_a_cancel_landing_while_the_job_writes_its_end_answers_with_the_ended_job(tmp_path: Path) -> None:
    # The job sees the cancel at its next step (the robot's stop ends its move) and starts writing its
    # record; the cancel's task.cancel() lands then. The answer must still be the ended job.
    async with running_service(tmp_path, _config(answers="all")) as service, api_client(service) as client:
        slow_moves(service, 200.0)
        await _command(client, "clear")
        job = await _laser_job_under_way(client)
        jobs = service.jobs
        writing = asyncio.Event()
        update_job, stop = jobs.store.update_job, jobs.devices.robot.stop

        async def slow_end(job_id: int, **fields: Any) -> Any:
            if fields.get("state") == "cancelled":
                writing.set()
                await asyncio.sleep(0.5)
            return await update_job(job_id, **fields)

        async def stop_then_let_the_job_end(*, timeout_s: float) -> None:
            await stop(timeout_s=timeout_s)
            await asyncio.wait_for(writing.wait(), 20.0)

        jobs.store.update_job = slow_end
        jobs.devices.robot.stop = stop_then_let_the_job_end
        r = await client.post(f"/jobs/{job['id']}/cancel", headers=AUTH)
        assert r.status_code == 200 and r.json()["state"] == "cancelled", r.text
        assert "cancelled by operator" in r.json()["error"]
        assert (await client.get("/status")).json().get("job") is None


async def test_a_packml_stop_cancels_the_job(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config(answers="all")) as service, api_client(service) as client:
        slow_moves(service, 200.0)
        await _command(client, "clear")
        assert await _command(client, "reset") == "IDLE"
        job = await _laser_job_under_way(client)
        assert await _command(client, "stop") == "STOPPED"
        done = await _wait_done(client, job["id"], timeout_s=10)
        assert done["state"] == "cancelled" and "stop" in done["error"], done
        assert service.orchestrator.machine.state is PackMLState.STOPPED


async def test_every_move_of_a_job_is_at_the_reduced_speed(tmp_path: Path) -> None:
    cfg = _config(answers="all", **{"calibration.procedure": {"speed_mm_s": 180.0, "speed_deg_s": 20.0}})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        seen: list[MotionRequest] = []
        robot = service.orchestrator.devices.robot
        inner = robot._robot
        original = inner.move

        async def recording(request: MotionRequest, *, timeout_s: float) -> Any:
            seen.append(request)
            return await original(request, timeout_s=timeout_s)

        inner.move = recording  # type: ignore[method-assign]
        await _command(client, "clear")
        job = await _start(client, "laser", poses=120)
        assert (await _wait_done(client, job["id"]))["state"] == "done"
        assert len(seen) == 120
        assert max(r.speed_mm_s for r in seen) <= 180.0 and max(r.speed_deg_s for r in seen) <= 20.0


def test_the_reduced_speed_is_capped_by_the_configuration() -> None:
    from cellctl.config import ConfigError

    with pytest.raises(ConfigError, match="calibration.procedure.speed_mm_s"):
        _config(**{"calibration.procedure": {"speed_mm_s": 400.0}})


async def test_a_refused_result_leaves_the_set_unchanged_and_says_why(tmp_path: Path) -> None:
    cfg = _config(answers="all", **{"calibration.procedure.laser": {"max_rms_mm": 0.001}})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        await _command(client, "clear")
        job = await _start(client, "laser", poses=120)
        done = await _wait_done(client, job["id"])
        assert done["state"] == "refused" and "rms" in done["error"].lower(), done
        assert done["version_after"] is None
        assert CalibrationStore(service.jobs.calibration_store.root).current() is None
        assert read_dataset(done["dataset"], "laser_plane").manifest["readings"]  # the full dataset is kept


async def test_a_dry_run_plans_without_moving(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        robot = service.orchestrator.devices.robot
        before = (await robot.read_pose(timeout_s=2.0)).to_matrix()
        r = await client.post("/jobs/plan?poses=true", json={"procedure": "camera", "options": {"views": 8}}, headers=AUTH)
        assert r.status_code == 200, r.text
        plan = r.json()
        assert plan["poses"] == 8 and len(plan["pose_list"]) == 8 and plan["estimated_robot_time_s"] > 0
        assert plan["rotation"]["axis_spread"] > 0.05 and plan["rotation"]["max_pair_angle_deg"] > 15
        after = (await robot.read_pose(timeout_s=2.0)).to_matrix()
        assert abs(after - before).max() < 1e-9
        r = await client.post("/jobs/plan", json={"procedure": "teaching"}, headers=AUTH)
        assert r.status_code == 422 and "camera must be calibrated first" in r.json()["detail"]
        assert (await client.get("/jobs")).json() == []  # a plan is not a job


async def test_the_event_stream_carries_job_progress_and_prompts(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config(answers="all")) as service, api_client(service) as client:
        await _command(client, "clear")
        queue = service.orchestrator.events.subscribe()
        job = await _start(client, "laser", poses=120)
        await _wait_done(client, job["id"])
        kinds: dict[str, int] = {}
        prompts = []
        while not queue.empty():
            ev = queue.get_nowait()
            if ev.data.get("job_id") == job["id"]:
                kinds[ev.kind] = kinds.get(ev.kind, 0) + 1
                if ev.kind == "prompt":
                    prompts.append((ev.data["prompt"]["kind"], ev.data["open"]))
            json.dumps(ev.data)  # JSON-ready
        assert kinds["job"] >= 100 and ("confirm_start", True) in prompts and ("confirm_start", False) in prompts


def test_the_commissioning_reference_in_docs_is_generated_from_the_code() -> None:
    from cellctl.commissioning.reference import render

    doc = Path(__file__).resolve().parents[2] / "docs" / "commissioning_reference.md"
    assert doc.read_text() == render(), (
        "docs/commissioning_reference.md is stale: run `python -m cellctl.commissioning.reference -o docs/commissioning_reference.md`"
    )
