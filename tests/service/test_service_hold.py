"""A Hold that lands in the middle of a cycle stops the cycle; the cell goes to Held, not Aborted."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from service_test_support import AUTH, api_client, running_service, to_execute

from cellctl.cell.alarms import AlarmCode
from cellctl.cell.cycle_values import CellDevices
from cellctl.cell.tags import PackMLState


class HoldingLaser:
    """Wraps the real laser; its first reading raises a Hold-class alarm, as a failing measurement would."""

    def __init__(self, inner: Any, alarms: Any) -> None:
        self._inner = inner
        self._alarms = alarms
        self._pending = True

    async def read(self, *, timeout_s: float) -> Any:
        if self._pending:
            self._pending = False
            await self._alarms.raise_alarm(AlarmCode.CORNER_NOT_FOUND, source="vision", detail="test: mid-cycle hold")
        return await self._inner.read(timeout_s=timeout_s)

    async def ping(self, *, timeout_s: float) -> float:
        return await self._inner.ping(timeout_s=timeout_s)

    async def close(self) -> None:
        await self._inner.close()


async def test_a_hold_mid_cycle_ends_the_cycle_as_stopped_and_the_cell_is_held(tmp_path: Path) -> None:
    async with running_service(tmp_path) as service, api_client(service) as client:
        orch = service.orchestrator
        d = orch.devices
        orch.devices = CellDevices(HoldingLaser(d.laser, orch.alarms), d.camera, d.robot)
        await to_execute(client)
        r = await client.post(
            "/cycle?wait=true&timeout_s=30", json={"recipe": "side-window", "part_id": "P"}, headers={**AUTH, "Idempotency-Key": "h"}
        )
        rec = r.json()
        assert rec["state"] == "failed" and rec["error"].startswith("stopped"), rec
        assert rec["install_started_at"] is None
        await orch.machine.wait_for_state(PackMLState.HELD, timeout_s=5.0)
        codes = [a["code"] for a in (await client.get("/alarms")).json()["current"]]
        assert int(AlarmCode.CORNER_NOT_FOUND) in codes and int(AlarmCode.TASK_FAILED) not in codes
