"""A PLC command refused by the state table and one held back by an interlock: two codes, and the reason logged."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import running_service, sim_config

from cellctl.cell.alarms import AlarmCode
from cellctl.cell.tags import PackMLCommand, PackMLState

pytestmark = pytest.mark.timeout(60)

NOT_ALLOWED = 1  # docs/plc_register_map.md, Codes: invalid_in_state
BLOCKED = 5  # docs/plc_register_map.md, Codes: blocked (an interlock)


def _refusals(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if "refused" in r.getMessage() and r.name.startswith("cellctl")]


async def test_table_refusal_and_interlock_refusal_get_their_own_cmd_result(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="cellctl")
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005, "heartbeat_alarm": False})
    async with running_service(tmp_path, cfg) as service:
        client = AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1)  # type: ignore[attr-defined]
        assert await client.connect()
        plc = PlcClient(client, cfg.plc.float_word_order, unit_id=cfg.plc.unit_id)
        try:
            assert PackMLState((await plc.read_cell())["state_current"]) is PackMLState.ABORTED
            start = await plc.command(PackMLCommand.START)  # Aborted has no Start edge: the table refuses
            assert start["cmd_result"] == NOT_ALLOWED, start
            assert any("Start refused in Aborted" in m and "state model does not allow it" in m for m in _refusals(caplog))

            assert (await plc.command(PackMLCommand.CLEAR))["cmd_result"] == 0
            assert PackMLState((await plc.read_cell())["state_current"]) is PackMLState.STOPPED
            alarm = await service.orchestrator.alarms.raise_alarm(AlarmCode.CORNER_NOT_FOUND, source="test")
            caplog.clear()
            reset = await plc.command(PackMLCommand.RESET)  # Stopped -> Resetting is an edge; the alarm holds it back
            assert reset["cmd_result"] == BLOCKED, reset
            assert PackMLState(reset["state_current"]) is PackMLState.STOPPED
            assert any("Reset refused in Stopped" in m and "acknowledge it first" in m for m in _refusals(caplog)), \
                _refusals(caplog)

            service.orchestrator.alarms.acknowledge(alarm.uid, by="test")
            assert (await plc.command(PackMLCommand.RESET))["cmd_result"] == 0
        finally:
            client.close()
