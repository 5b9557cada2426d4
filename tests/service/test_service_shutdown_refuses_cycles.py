"""Once the service is stopping (SIGTERM or Ctrl-C came: Service._end_work_then_close_streams), a new cycle request is
refused saying so (it was stored and never ran, marked interrupted at the next start) and the PLC's ready flag drops.
The peers: httpx against the REST API and pymodbus reading the cell block."""

from __future__ import annotations

from pathlib import Path

import pytest
from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

pytestmark = pytest.mark.timeout(60)


async def test_a_cycle_asked_for_while_the_service_stops_is_refused_and_ready_drops(tmp_path: Path) -> None:
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005, "heartbeat_alarm": False})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        modbus = AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1)  # type: ignore[attr-defined]
        assert await modbus.connect()
        plc = PlcClient(modbus, cfg.plc.float_word_order, unit_id=cfg.plc.unit_id)
        try:
            await to_execute(client)
            await plc.wait_cell(lambda c: c["ready"], "ready in Execute")
            await service.orchestrator.end_for_shutdown("the service is stopping")  # what the signal handler runs first
            r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "P-late"},
                                  headers={**AUTH, "Idempotency-Key": "late-1"})
            assert r.status_code >= 400 and "the service is stopping" in r.text, r.text
            assert (await client.get("/cycles")).json() == []  # nothing stored to be marked interrupted later
            await plc.wait_cell(lambda c: not c["ready"], "ready dropped")
        finally:
            modbus.close()
