"""A failed cycle's record carries the twin's install error only when a glass went into the opening.

Before the install marker the glass is still on the gripper, wherever the robot stopped: its "error"
against the opening is the robot's distance from it (hundreds of mm), not an install error. Scored
against the twin's own truth: whether it holds a released glass, and where.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

pytestmark = pytest.mark.timeout(120)


def _config() -> Any:
    return sim_config(
        plc={"enabled": False},
        **{"alarms.watchdog": {"period_s": 0.2, "timeout_s": 0.15, "miss_threshold": 2},
           "process.motion": {"grab_timeout_s": 1.0, "read_timeout_s": 1.0}},
    )  # fmt: skip


async def _failed_cycle(service: Any, key: str) -> dict[str, Any]:
    async with api_client(service) as client:
        await to_execute(client)
        r = await client.post("/cycle?wait=true&timeout_s=60", json={"recipe": "side-window", "part_id": key},
                              headers={**AUTH, "Idempotency-Key": key})  # fmt: skip
        assert r.status_code in (200, 201), r.text
        return dict((await client.get(f"/cycles/{r.json()['id']}")).json())


async def test_a_cycle_failed_before_its_install_has_no_install_error(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config()) as service:
        service.extras["fakes"]["laser"].silence(count=None)  # the alignment cannot read the wall
        rec = await _failed_cycle(service, "no-wall")
        cell = service.extras["twin"].cell
        assert rec["state"] == "failed" and rec["install_started_at"] is None, rec
        assert cell.installed_glass() is None and cell.glass_on_gripper  # truth: no glass went in
        assert rec["true_error"] is None, rec["true_error"]


async def test_a_cycle_failed_after_its_install_keeps_the_install_error(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config()) as service:
        cell = service.extras["twin"].cell
        laser = service.extras["fakes"]["laser"]
        release = cell.set_gripper

        def set_gripper(hold: bool) -> None:
            released = not hold and cell.glass_on_gripper
            release(hold)
            if released:  # the glass is in: the inspection's laser falls silent
                laser.silence(count=None)

        cell.set_gripper = set_gripper
        rec = await _failed_cycle(service, "no-inspection")
        assert rec["install_started_at"] is not None and cell.installed_glass() is not None, rec
        assert rec["state"] == "failed", rec
        truth = cell.install_error()
        assert rec["true_error"] is not None
        for axis, value in rec["true_error"].items():
            assert value == pytest.approx(getattr(truth, axis), abs=1e-9), axis
        assert max(abs(rec["true_error"][k]) for k in ("dx_mm", "dy_mm", "dz_mm")) < 0.5  # an install's error
