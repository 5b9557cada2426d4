"""``[plc] allowed_clients``: only the listed addresses may connect to the Modbus TCP server (review r4, D5).

The clients are pymodbus's own AsyncModbusTcpClient, bound to a chosen loopback source address.
"""

from __future__ import annotations

import asyncio
import logging

import pytest
from plc_test_support import MemoryCell, plc_config, running_cell
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException

from cellctl.cell.tags import PackMLCommand, PackMLState
from cellctl.plc import PlcServer
from cellctl.plc.register_map import register


async def test_an_allowed_client_commands_the_cell() -> None:
    cell = MemoryCell()
    async with running_cell(cell, allowed_clients=["127.0.0.1"]) as (_server, plc):
        await plc.command(int(PackMLCommand.STOP))
    assert cell.commands == [PackMLCommand.STOP] and cell.state is PackMLState.STOPPED


async def _send_stop(port: int, source: str) -> str:
    """cntrl_cmd = Stop with cmd_change_request from ``source``: what the server answered, or why nothing."""
    client = AsyncModbusTcpClient("127.0.0.1", port=port, source_address=(source, 0), timeout=1, retries=0,
                                  reconnect_delay=0)  # fmt: skip
    try:
        if not await client.connect():
            return "not connected"
        await asyncio.sleep(0.2)  # a refused connection is closed as soon as it is accepted
        start = register("cntrl_cmd").address
        rr = await client.write_registers(start, [int(PackMLCommand.STOP), 1], device_id=1)
        return "error response" if rr.isError() else "written"
    except ModbusException as err:
        return f"failed: {type(err).__name__}"
    finally:
        client.close()


async def test_a_client_outside_allowed_clients_is_closed_and_commands_nothing(caplog: pytest.LogCaptureFixture) -> None:
    cell = MemoryCell()
    server = PlcServer(plc_config(allowed_clients=["127.0.0.2"]), cell)
    await server.start()
    try:
        with caplog.at_level(logging.WARNING):
            first = await _send_stop(server.port, "127.0.0.1")
            second = await _send_stop(server.port, "127.0.0.1")
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port, local_addr=("127.0.0.1", 0))
        assert await asyncio.wait_for(reader.read(16), 2.0) == b""  # closed by the server before a byte was sent
        writer.close()
        await asyncio.sleep(0.3)  # two scans: a written command would have reached the cell by now
        assert first.startswith(("failed", "not connected")) and second.startswith(("failed", "not connected")), (first, second)
        assert cell.commands == [] and cell.state is PackMLState.IDLE
        refusals = [r.getMessage() for r in caplog.records if "allowed_clients" in r.getMessage()]
        assert len(refusals) == 1 and "127.0.0.1" in refusals[0], refusals  # logged once, with the peer
        assert await _send_stop(server.port, "127.0.0.2") == "written"  # the listed address gets through
        for _ in range(100):
            if cell.commands:
                break
            await asyncio.sleep(0.02)
        assert cell.commands == [PackMLCommand.STOP]
    finally:
        await server.stop()
        await cell.drain()


def test_allowed_clients_refuses_what_is_not_an_address_or_network() -> None:
    with pytest.raises(ValueError, match=r"plc.allowed_clients: '10.1.2.3/24' is not an IP address or network"):
        plc_config(allowed_clients=["10.1.2.3/24"])
    assert "any host" in plc_config().clients_note() and "allowed_clients" in plc_config().clients_note()
