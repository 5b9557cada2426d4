"""A Hold or Abort that lands just as the gripper has released the glass (the inspection's back-off moves come next)
ends the cycle as stopped, and the controller gets no motion and no gripper command after the cell's STOP (the cancel
was dropped as the stopped move's answer arrived, and the cycle ran on to `done` under Holding or Aborting). The peer:
the lines the ABB controller fake received on its RAPID socket."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
from service_test_support import AUTH, api_client, running_service
from test_fault_injection import _config, _finished, _recover, _settled, _submit, _to_execute

pytestmark = pytest.mark.timeout(120)

MOTION = ("MOVEL", "MOVEJ", "GRIP")  # docs of the RAPID verbs: motion and the gripper's io


@pytest.mark.parametrize(("command", "state"), [("hold", "HELD"), ("abort", "ABORTED")])
async def test_a_command_as_the_glass_is_released_stops_the_cycle_and_every_motion(
        tmp_path: Path, command: str, state: str) -> None:
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        fake = service.extras["fakes"]["robot"]
        await _to_execute(client)
        driver = service.orchestrator.robot.inner  # the ABB driver under the cell's robot port
        release, sent = driver.set_gripper, []

        async def set_gripper(hold: bool, *, timeout_s: float) -> Any:
            done = await release(hold, timeout_s=timeout_s)
            if not hold and not sent:  # the glass is in the car body: the operator presses the command now
                sent.append(asyncio.create_task(client.post(f"/commands/{command}", headers=AUTH)))
            return done

        driver.set_gripper = set_gripper
        cid = await _submit(client, f"{command}-at-release")
        rec = await _finished(client, cid)
        assert sent and (await sent[0]).status_code == 200
        lines = [line.split()[1] for line in fake.server.lines_received if len(line.split()) > 1]  # "<id> <VERB> ..."
        stop = max(i for i, verb in enumerate(lines) if verb == "STOP")
        assert [v for v in lines[stop + 1:] if v in MOTION] == [], lines[stop - 3:]
        assert rec["state"] == "failed" and rec["error"].startswith("stopped: the cell went to"), rec["error"]
        assert rec["install_started_at"] is not None  # the glass is in: the PLC sees install_started, nok
        assert await _settled(client) == state
        del driver.set_gripper
        await _recover(client)
