"""A device lost at start: the cell stands in Aborted (its start state) and /status names the lost device's
alarm as the stop reason, kept through Clear until a Reset ends the stop."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest
from service_test_support import AUTH, api_client, sim_config
from shared_support import eventually

from cellctl.cell.alarms import AlarmCode
from cellctl.service import build_service

pytestmark = pytest.mark.timeout(60)


async def _status(client: httpx.AsyncClient) -> dict:
    return dict((await client.get("/status")).json())


async def test_a_laser_lost_at_start_is_the_stop_reason_of_the_aborted_cell(tmp_path: Path) -> None:
    cfg = sim_config(plc={"enabled": False}, **{"alarms.watchdog": {"period_s": 0.2, "timeout_s": 0.15, "miss_threshold": 2}})
    service = await build_service(cfg, workdir=tmp_path)
    laser = service.extras["fakes"]["laser"]
    laser.silence(count=None)  # the LK-G controller does not answer from the start
    await service.start()
    try:
        async with api_client(service) as client:

            async def laser_link(state: str) -> bool:
                return (await _status(client))["devices"]["laser"]["link"] == state

            await eventually("the watchdog sees the laser lost", lambda: laser_link("lost"))
            status = await _status(client)
            assert status["state"] == "ABORTED"
            assert status["stop_reason"] is not None, "Aborted at start with the laser lost, and no stop reason"
            assert status["stop_reason"]["code"] == int(AlarmCode.LASER_LOST), status["stop_reason"]
            assert "laser" in status["stop_reason"]["message"].lower()

            laser.speak()
            assert (await client.post("/commands/clear", headers=AUTH)).status_code == 200
            await eventually("the laser answers again", lambda: laser_link("up"))
            assert (await client.post("/alarms/acknowledge-all", headers=AUTH)).status_code == 200
            await eventually("Stopped", lambda: _is_stopped(client))
            assert (await _status(client))["stop_reason"]["code"] == int(AlarmCode.LASER_LOST)  # kept in Stopped
            assert (await client.post("/commands/reset", headers=AUTH)).status_code == 200
            assert (await _status(client))["stop_reason"] is None  # a Reset ends the stop
    finally:
        await service.stop()


async def _is_stopped(client: httpx.AsyncClient) -> bool:
    return (await _status(client))["state"] == "STOPPED"
