"""A laser lost while the cell is Idle stops nothing (Hold is no edge from Idle), so ``stop_reason_id`` stays 0; the
PLC's Start is held back (cmd_result 5) and ``interlock_alarm_id`` names the alarm that holds it, until the laser
answers again. The peers: pymodbus reading the register map as docs/plc_register_map.md gives it, and the LK-G fake
falling silent on its serial line."""

from __future__ import annotations

from pathlib import Path

import pytest
from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import running_service, sim_config

from cellctl.cell.tags import PackMLCommand, PackMLState

pytestmark = pytest.mark.timeout(90)

BLOCKED = 5  # docs/plc_register_map.md, Codes: blocked (an interlock)
LASER_LOST = 1101  # docs/alarm_reactions.md
INTERLOCK_ALARM_ID = 152  # docs/plc_register_map.md, the cell block


async def _register(client: AsyncModbusTcpClient, address: int) -> int:
    rr = await client.read_holding_registers(address, count=1, device_id=1)
    assert not rr.isError(), rr
    return int(rr.registers[0])


async def test_a_laser_lost_in_idle_is_named_to_the_plc_as_the_interlock_holding_start(tmp_path: Path) -> None:
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005, "heartbeat_alarm": False},
                     **{"alarms.watchdog": {"period_s": 0.2, "timeout_s": 0.15, "miss_threshold": 2}})
    async with running_service(tmp_path, cfg) as service:
        client = AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1)  # type: ignore[attr-defined]
        assert await client.connect()
        plc = PlcClient(client, cfg.plc.float_word_order, unit_id=cfg.plc.unit_id)
        laser = service.extras["fakes"]["laser"]
        try:
            for cmd in (PackMLCommand.CLEAR, PackMLCommand.RESET):
                assert (await plc.command(cmd))["cmd_result"] == 0
            cell = await plc.read_cell()
            assert PackMLState(cell["state_current"]) is PackMLState.IDLE
            assert (cell["interlock_alarm_id"], cell["stop_reason_id"]) == (0, 0), cell

            laser.silence(count=None)  # the LK-G controller stops answering
            cell = await plc.wait_cell(lambda c: c["interlock_alarm_id"] != 0, "the laser's alarm named", timeout_s=30.0)
            assert cell["interlock_alarm_id"] == LASER_LOST == await _register(client, INTERLOCK_ALARM_ID), cell
            assert PackMLState(cell["state_current"]) is PackMLState.IDLE and cell["stop_reason_id"] == 0, cell
            start = await plc.command(PackMLCommand.START)
            assert start["cmd_result"] == BLOCKED and start["interlock_alarm_id"] == LASER_LOST, start

            laser.speak()
            await plc.wait_cell(lambda c: c["interlock_alarm_id"] == 0, "the interlock gone", timeout_s=30.0)
            assert await _register(client, INTERLOCK_ALARM_ID) == 0
            assert (await plc.command(PackMLCommand.START))["cmd_result"] == 0
        finally:
            laser.speak()
            client.close()
