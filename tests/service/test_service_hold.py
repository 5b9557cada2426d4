"""A Hold that lands in the middle of a cycle stops the cycle; the cell goes to Held, not Aborted."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from service_test_support import AUTH, api_client, running_service, to_execute

from cellctl.cell.alarms import AlarmCode
from cellctl.cell.tags import PackMLState


class HoldingCalibration:
    """Wraps the real source; its self-calibration raises a Hold-class alarm, as a failing sensor would."""

    def __init__(self, inner: Any, alarms: Any) -> None:
        self._inner = inner
        self._alarms = alarms
        self._pending = True

    def problems(self) -> list[str]:
        return ["camera: missing"] if self._pending else self._inner.problems()

    def cycle_calibration(self) -> Any:
        return self._inner.cycle_calibration()

    def summary(self) -> dict[str, Any]:
        return self._inner.summary()

    async def calibrate(self) -> None:
        self._pending = False
        await self._alarms.raise_alarm(AlarmCode.CORNER_NOT_FOUND, source="vision", detail="test: mid-cycle hold")


async def test_a_hold_mid_cycle_ends_the_cycle_as_stopped_and_the_cell_is_held(tmp_path: Path) -> None:
    async with running_service(tmp_path) as service, api_client(service) as client:
        orch = service.orchestrator
        orch.calibration = HoldingCalibration(orch.calibration, orch.alarms)
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
