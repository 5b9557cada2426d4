"""The PLC tells a cycle stopped before the install from one aborted during it (cycle_flags bit 8, map 1.5).

On the whole simulated cell, a pymodbus PLC: cycle 31 is held by the operator in align, cycle 32 aborted by
the PLC in install. Both end nok 1309; ``install_started`` tells them apart, as the store's install marker
(read with sqlite3) and the twin (the flange nearer the wall than any shooting pose) say. After the abort,
robot_clear stays 0 even with the robot moved well clear: that car body may hold a glass half in.
"""

from __future__ import annotations

import asyncio
import sqlite3
from pathlib import Path

import pytest
from plc_test_support import PlcClient
from service_test_support import AUTH, api_client, running_service, sim_config, slow_moves
from test_plc_car_body_and_robot_clear import (
    CLEAR_MM,
    connected_plc,
    move_to_true_distance,
    true_wall_distance_mm,
)

from cellctl.cell.tags import CycleStep, PackMLCommand, PackMLState

pytestmark = pytest.mark.timeout(280)
SHOOTING_MM = 342.0  # the twin's flange-to-wall distance at the shooting pose: the install goes nearer


def install_marker(service: object, key: str) -> str | None:
    db = Path(service.workdir) / service.config.store.path  # type: ignore[attr-defined]
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as con:
        row = con.execute("SELECT install_started_at FROM cycles WHERE idempotency_key = ?", (key,)).fetchone()
    return row[0]


async def request(plc: PlcClient, req_id: int, part: int) -> None:
    await plc.wait_cell(lambda c: c["ready"], "ready", 60.0)
    await plc.write(recipe_id=1, part_id=part, cycle_req_id=req_id, cycle_request=1)


async def test_install_started_tells_a_hold_in_align_from_an_abort_in_install(tmp_path: Path) -> None:
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005})
    async with running_service(tmp_path, cfg) as service, api_client(service) as api:
        await asyncio.to_thread(service.orchestrator.calibration.cycle_calibration)
        client, plc = await connected_plc(service)
        slow_moves(service, 30.0)
        try:
            await request(plc, 31, 3101)
            await plc.wait_cell(lambda c: c["busy"] and c["cycle_step"] == CycleStep.ALIGN, "align", 60.0)
            assert (await api.post("/commands/hold", headers=AUTH)).status_code == 200
            held = await plc.wait_cell(lambda c: c["done"] and c["cycle_ack_id"] == 31, "done after hold", 60.0)
            await plc.write(cycle_request=0)
            await plc.wait_cell(lambda c: not c["done"], "cleared")
            await plc.wait_cell(lambda c: c["state_current"] == int(PackMLState.HELD), "Held", 30.0)  # not Holding
            assert (await plc.command(int(PackMLCommand.UNHOLD)))["cmd_result"] == 0

            await request(plc, 32, 3201)
            await plc.wait_cell(lambda c: c["busy"] and c["cycle_step"] == CycleStep.INSTALL
                                and true_wall_distance_mm(service) < SHOOTING_MM - 20.0, "on the way in", 120.0)
            assert (await plc.command(int(PackMLCommand.ABORT)))["cmd_result"] == 0
            aborted = await plc.wait_cell(lambda c: c["done"] and c["cycle_ack_id"] == 32, "done after abort", 60.0)
            at_abort = true_wall_distance_mm(service)
            await plc.write(cycle_request=0)

            assert held["nok"] and aborted["nok"] and held["error_code"] == aborted["error_code"]
            assert install_marker(service, "31") is None and install_marker(service, "32") is not None
            assert not held["install_started"]
            assert aborted["install_started"]
            assert at_abort < SHOOTING_MM, at_abort  # the twin: the glass was on its way into the opening

            # the car body of an aborted install is never reported clear, however far the robot goes
            slow_moves(service, 1 / 30.0)
            truth = await move_to_true_distance(service, 420.0)
            assert truth >= CLEAR_MM + 50.0
            await asyncio.sleep(1.0)  # five readings
            assert not (await plc.read_cell())["robot_clear"], truth
            # repeating id 32 replays its result with the bit (the store's marker, across the link)
            again = await plc.run_cycle(32, 1, 3201)
            assert again["replayed"] and again["install_started"] and again["error_code"] == aborted["error_code"]
        finally:
            await plc.stop_heartbeat()
            client.close()
