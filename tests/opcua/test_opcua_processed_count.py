"""OPC UA's Admin.ProcessedCount counts the glasses the cell used: a cycle done, and one held after its glass was
released into the car body (its install began; the PLC reads install_started with nok); that one is defective too.
The peers: asyncua's client reading the counters, and the lines the ABB controller fake received (GRIP 0)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua
from opcua_test_support import call, ns_of, opcua_client, secure_config, to_execute, wait_value
from service_test_support import AUTH, api_client, running_service

pytestmark = pytest.mark.timeout(120)


def _releases(fake: Any) -> int:
    return sum(1 for line in fake.server.lines_received if line.split()[1:3] == ["GRIP", "0"])


async def test_a_glass_released_then_held_counts_as_processed_and_defective(tmp_path: Path) -> None:
    async with running_service(tmp_path, secure_config()) as service, api_client(service) as rest:
        async with opcua_client(service, tmp_path) as client:
            ns = await ns_of(client)
            await to_execute(client, ns)
            first = await call(client, ns, "Cycle.StartCycle", "side-window", "P-1", "", "req-1")
            await wait_value(client, ns, "Cycle.LastResult.CycleId", lambda v: v == first, "the first cycle ends", 60)

            driver = service.orchestrator.robot.inner  # the ABB driver: the operator holds as the glass is released
            release, sent = driver.set_gripper, []

            async def set_gripper(hold: bool, *, timeout_s: float) -> Any:
                done = await release(hold, timeout_s=timeout_s)
                if not hold and not sent:
                    sent.append(asyncio.create_task(rest.post("/commands/hold", headers=AUTH)))
                return done

            driver.set_gripper = set_gripper
            second = await call(client, ns, "Cycle.StartCycle", "side-window", "P-2", "", "req-2")
            await wait_value(client, ns, "Cycle.LastResult.CycleId", lambda v: v == second, "the held cycle ends", 60)
            del driver.set_gripper
            rec = (await rest.get(f"/cycles/{second}")).json()
            assert rec["state"] == "failed" and rec["install_started_at"] is not None, rec["error"]
            assert _releases(service.extras["fakes"]["robot"]) == 2  # two glasses left the gripper
            counts = [await client.get_node(ua.NodeId(f"cell-1.Admin.{n}", ns)).read_value()
                      for n in ("ProcessedCount", "DefectiveCount")]
            assert counts == [2, 1], counts
