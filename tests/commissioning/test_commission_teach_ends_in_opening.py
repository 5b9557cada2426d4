"""A teaching job that ends while the glass stands in the car body's opening says so, and what to do first.

Scored against the twin's truth (where the glass on the gripper really is, against the opening) and the job's
record and last event: between the first hand-guided install and the retreat, a cancel or a fault leaves the
glass in the opening, and the next job or cycle would make its first move from there.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_test_support import AUTH, api_client, running_service
from test_commission_jobs import _command, _config, _wait_done
from test_service_parts import commit_as_set

from cellctl.commissioning.prompts import PromptKind
from cellctl.ports import DeviceTimeout
from cellctl.sim import operator as sim_operator

pytestmark = [pytest.mark.timeout(240), pytest.mark.asyncio]


def _teaching_config() -> Any:
    return _config(answers="actions", calibration={"source": "oracle", "auto_calibrate_in_sim": False},
                   **{"sim.operator": {"answers": "actions", "answer_delay_s": 0.3}})  # fmt: skip


async def _seeded(service: Any, tmp_path: Path, client: httpx.AsyncClient) -> None:
    """The calibration set from the twin's truth (the teaching needs hand-eye and laser); the cell Stopped."""
    oracle = await asyncio.to_thread(service.orchestrator.calibration.cycle_calibration)
    service.jobs.calibration_store = commit_as_set(tmp_path / "calibration", oracle)
    await _command(client, "clear")


async def _until_prompt(client: httpx.AsyncClient, jid: int, kind: str, index: int | None = None) -> dict[str, Any]:
    """Confirm the start (the engineer's word) and wait for prompt ``kind`` (its ``index``-th, for installs)."""
    deadline = time.monotonic() + 150
    while time.monotonic() < deadline:
        job = (await client.get(f"/jobs/{jid}")).json()
        assert job["state"] == "running", job
        p = job["prompt"]
        if p and p["kind"] == "confirm_start" and kind != "confirm_start":
            await client.post(f"/jobs/{jid}/prompts/{p['id']}", json={"action": "confirm"}, headers=AUTH)
        elif p and p["kind"] == kind and (index is None or p["details"].get("index") == index):
            return p
        await asyncio.sleep(0.05)
    raise AssertionError(f"no {kind} prompt")


def _glass_in_opening(service: Any) -> dict[str, float]:
    err = service.extras["twin"].cell.install_error().as_dict()  # the glass on the gripper against the opening
    assert max(abs(v) for k, v in err.items() if k.endswith("_mm")) < 5.0, err  # the truth: it stands in the opening
    return err


def _says_jog_out(text: str | None) -> bool:
    t = (text or "").lower()
    return "opening" in t and "jog it" in t and "before any job or cycle moves it" in t and "c_pos_0" in t


async def test_a_teaching_cancelled_at_the_retreat_says_the_glass_is_in_the_opening(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The engineer cancels at the retreat prompt; the simulated operator leaves that prompt alone, so it does not jog
    # the glass out first (it would, answer_delay_s after the prompt: a race a loaded host lost once).
    monkeypatch.setattr(sim_operator, "_ACTIONS", sim_operator._ACTIONS - {PromptKind.RETREAT})  # noqa: SLF001
    async with running_service(tmp_path, _teaching_config()) as service, api_client(service) as client:
        await _seeded(service, tmp_path, client)
        # Cancelled before anything went near the opening: nothing to say about it.
        jid = (await client.post("/jobs", json={"procedure": "teaching"}, headers=AUTH)).json()["id"]
        await _until_prompt(client, jid, "confirm_start")
        assert (await client.post(f"/jobs/{jid}/cancel", headers=AUTH)).status_code == 200
        early = await _wait_done(client, jid)
        assert early["state"] == "cancelled" and "opening" not in (early["error"] or ""), early
        # Cancelled at the retreat prompt: the glass is still in the opening.
        events = service.orchestrator.events.subscribe()
        jid = (await client.post("/jobs", json={"procedure": "teaching"}, headers=AUTH)).json()["id"]
        await _until_prompt(client, jid, "retreat")
        assert (await client.post(f"/jobs/{jid}/cancel", headers=AUTH)).status_code == 200
        done = await _wait_done(client, jid)
        _glass_in_opening(service)
        assert done["state"] == "cancelled" and done["error"].startswith("cancelled by"), done
        assert _says_jog_out(done["error"]) and "install 3" in done["error"], done["error"]
        last = None
        while not events.empty():
            ev = events.get_nowait()
            if ev.kind == "job" and ev.data["job_id"] == jid:
                last = ev.data
        service.orchestrator.events.unsubscribe(events)
        assert last is not None and last["state"] == "cancelled" and _says_jog_out(last["error"]), last


async def test_a_teaching_that_fails_between_the_installs_says_the_glass_is_in_the_opening(tmp_path: Path) -> None:
    async with running_service(tmp_path, _teaching_config()) as service, api_client(service) as client:
        await _seeded(service, tmp_path, client)
        jid = (await client.post("/jobs", json={"procedure": "teaching"}, headers=AUTH)).json()["id"]
        await _until_prompt(client, jid, "guide_install", index=2)  # install 1 is recorded: the glass went in

        async def silent(*, timeout_s: float) -> Any:
            raise DeviceTimeout("robot", "no answer to the pose request")

        service.jobs.devices.robot.read_pose = silent  # the robot controller stops answering
        done = await _wait_done(client, jid, timeout_s=60)
        _glass_in_opening(service)
        assert done["state"] == "failed" and "DeviceTimeout" in done["error"], done
        assert _says_jog_out(done["error"]), done["error"]
