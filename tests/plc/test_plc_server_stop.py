"""The PLC interface stops promptly (SIGTERM) even while the cell's answer to a cycle request is arriving."""

from __future__ import annotations

import asyncio

from plc_test_support import MemoryCell, PlcClient, plc_config
from pymodbus.client import AsyncModbusTcpClient

from cellctl.plc import PlcServer


class AnswersLate(MemoryCell):
    """The cell, answering a cycle request only when told to."""

    def __init__(self) -> None:
        super().__init__()
        self.release = asyncio.Event()

    async def start_cycle(self, req_id: int, recipe_id: int, part_id: int):  # type: ignore[no-untyped-def, override]
        await self.release.wait()
        return await super().start_cycle(req_id, recipe_id, part_id)


async def test_stop_returns_while_a_cycle_request_is_being_answered() -> None:
    cell = AnswersLate()
    cfg = plc_config(scan_period_s=1.0, cell_heartbeat_period_s=1.0, heartbeat_timeout_s=3.0)
    server = PlcServer(cfg, cell)
    await server.start()
    client = AsyncModbusTcpClient("127.0.0.1", port=server.port, timeout=2, retries=1)
    plc = PlcClient(client, cfg.float_word_order)
    assert await client.connect()
    try:
        await plc.wait_cell(lambda c: c["ready"], "ready")
        await plc.write(recipe_id=1, part_id=5, cycle_req_id=77, cycle_request=1)
        await asyncio.sleep(0.2)
    finally:
        client.close()
    cell.release.set()  # the cell answers start_cycle just as the service stops
    try:
        await asyncio.wait_for(server.stop(), 5.0)
    finally:
        await cell.drain()
