"""In Manual mode a technician works in the cell: no requester may start an automatic install, even in Execute."""

from __future__ import annotations

from pathlib import Path

from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import AUTH, _command, api_client, running_service, sim_config

from cellctl.plc.register_map import PlcErrorCode


async def test_manual_mode_takes_no_cycle_from_rest_or_the_plc_and_production_does(tmp_path: Path) -> None:
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005})
    async with running_service(tmp_path, cfg) as service, api_client(service) as rest:
        client = AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1)  # type: ignore[attr-defined]
        assert await client.connect()
        plc = PlcClient(client, cfg.plc.float_word_order, unit_id=cfg.plc.unit_id)
        try:
            for cmd in ("clear", "reset"):
                await _command(rest, cmd)
            assert (await rest.post("/mode/manual", headers=AUTH)).status_code == 200
            assert await _command(rest, "start") == "EXECUTE"
            status = (await rest.get("/status")).json()
            assert (status["state"], status["mode"]) == ("EXECUTE", "MANUAL")
            await plc.wait_cell(lambda c: c["state_current"] == 6 and c["unit_mode_current"] == 3, "Execute in Manual")
            assert not (await plc.read_cell())["ready"]
            r = await rest.post("/cycle", json={"recipe": "side-window", "part_id": "M-1"}, headers={**AUTH, "Idempotency-Key": "m1"})
            assert r.status_code == 409 and "the unit mode is Manual" in r.text, r.text
            await plc.write(recipe_id=1, part_id=42, cycle_req_id=9001, cycle_request=1)
            done = await plc.wait_cell(lambda c: c["done"] and c["cycle_ack_id"] == 9001, "the PLC's refusal", 30.0)
            await plc.write(cycle_request=0)
            assert done["error_code"] == int(PlcErrorCode.NOT_READY) and not done["ok"], done
            assert [c for c in await service.store.cycles(limit=10) if c.install_started_at is not None] == []
            # back to Production (modes change in Stopped): the same request is taken
            await _command(rest, "stop")
            await _command(rest, "reset")
            assert (await rest.post("/mode/production", headers=AUTH)).status_code == 200
            assert await _command(rest, "start") == "EXECUTE"
            r = await rest.post("/cycle?wait=true&timeout_s=60", json={"recipe": "side-window", "part_id": "P-1"},
                                headers={**AUTH, "Idempotency-Key": "p1"})  # fmt: skip
            assert r.status_code == 200 and r.json()["state"] == "done", r.text
        finally:
            client.close()
