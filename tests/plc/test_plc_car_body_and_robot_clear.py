"""On the whole simulated cell, a pymodbus PLC gives a car body id and waits for robot_clear.

- car_body_id (map 1.5) is the cycle's car id: the store (read with sqlite3), GET /parts?car_id= and the
  result block's echo all carry it.
- robot_clear is never 1 while the cycle runs, comes after done, and follows the twin's TRUE flange-to-wall
  distance against [plc] clear_distance_mm when the robot is moved afterwards.
"""

from __future__ import annotations

import asyncio
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import api_client, running_service, sim_config

from cellctl.cell.tags import PackMLCommand
from cellctl.geometry.pose import make_pose
from cellctl.ports import CartesianPose, MotionRequest
from cellctl.service.compose import Service

pytestmark = pytest.mark.timeout(240)
CAR_BODY = 4_000_000_123  # above 65535: both words of the uint32 count
CLEAR_MM = 350.0  # [plc] clear_distance_mm's default


def true_wall_distance_mm(service: Service) -> float:
    """The twin's truth: how far the flange stands in front of the car body's wall (along its normal, mm)."""
    cell = service.extras["twin"].cell  # type: ignore[attr-defined]
    T = cell.world().T_B_T
    n = T[:3, 2]
    return float(n @ T[:3, 3] - n @ cell.true_flange_pose()[:3, 3])


async def move_to_true_distance(service: Service, distance_mm: float) -> float:
    """Move the flange along the true wall normal so that it stands ``distance_mm`` in front of the wall; the truth after."""
    orch, cell = service.orchestrator, service.extras["twin"].cell  # type: ignore[attr-defined]
    n = cell.world().T_B_T[:3, 2]
    here = (await orch.robot.read_pose(timeout_s=2.0)).to_matrix()
    step = true_wall_distance_mm(service) - distance_mm  # + = towards the wall
    target = make_pose(np.eye(3), n * step) @ here
    await orch.robot.move(MotionRequest(CartesianPose.from_matrix(target), "linear", 200.0), timeout_s=30.0)
    return true_wall_distance_mm(service)


async def connected_plc(service: Service) -> tuple[AsyncModbusTcpClient, PlcClient]:
    client = AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1)  # type: ignore[attr-defined]
    assert await client.connect()
    plc = PlcClient(client, service.config.plc.float_word_order, unit_id=service.config.plc.unit_id)
    plc.start_heartbeat(0.1)
    for cmd in (PackMLCommand.CLEAR, PackMLCommand.RESET, PackMLCommand.START):
        assert (await plc.command(int(cmd)))["cmd_result"] == 0, cmd
    return client, plc


async def test_the_car_body_id_is_recorded_and_robot_clear_follows_the_true_distance(tmp_path: Path) -> None:
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005})
    async with running_service(tmp_path, cfg) as service, api_client(service) as api:
        client, plc = await connected_plc(service)
        try:
            first = await plc.wait_cell(lambda c: c["ready"], "ready", 60.0)
            assert first["map_version_major"] == 1 and first["map_version_minor"] >= 5  # car_body_id came in 1.5
            await plc.write(recipe_id=1, part_id=5001, cycle_req_id=501, cycle_request=1, car_body_id=CAR_BODY)
            seen: list[dict[str, Any]] = []

            def running(c: dict[str, Any]) -> bool:
                seen.append(c)
                return c["done"] and c["cycle_ack_id"] == 501

            done = await plc.wait_cell(running, "done for 501", 120.0)
            assert done["ok"] and done["install_started"] and done["result_car_body_id"] == CAR_BODY
            await plc.write(cycle_request=0)

            # the car body id is the cycle's car id: in the store (sqlite3) and over REST
            db = Path(service.workdir) / service.config.store.path
            with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as con:
                row = con.execute("SELECT car_id, part_id FROM cycles WHERE idempotency_key = '501'").fetchone()
            assert row == (str(CAR_BODY), "5001")
            parts = (await api.get("/parts", params={"car_id": str(CAR_BODY)})).json()["installs"]
            assert [(p["part_id"], p["car_id"], p["source"]) for p in parts] == [("5001", str(CAR_BODY), "plc")]

            # robot_clear: 0 before (no wall known) and all through the cycle, 1 after done at the twin's end pose
            assert service.config.plc.clear_distance_mm == CLEAR_MM
            assert not first["robot_clear"]
            busy = [c for c in seen if c["busy"]]
            assert busy and not any(c["robot_clear"] for c in busy), "robot_clear while the cycle ran"
            clear = await plc.wait_cell(lambda c: c["robot_clear"], "robot_clear after done", 10.0)
            assert not clear["busy"]
            at_end = true_wall_distance_mm(service)
            assert at_end >= CLEAR_MM, at_end  # the twin's end pose of a normal cycle (about 389 mm) counts as clear

            # moved towards the wall, then back out: robot_clear follows the true distance against 350 mm
            for want, clear_expected in ((320.0, False), (380.0, True), (330.0, False)):
                truth = await move_to_true_distance(service, want)
                assert abs(truth - want) < 5.0 and (truth >= CLEAR_MM) is clear_expected, truth
                await plc.wait_cell(lambda c, e=clear_expected: c["robot_clear"] is e, f"robot_clear {clear_expected} at {truth:.1f} mm", 10.0)
                await asyncio.sleep(0.6)  # three more readings: it stays
                assert (await plc.read_cell())["robot_clear"] is clear_expected, truth

            # a repeat of the id with another car body is flagged; the stored car body stands
            again = await plc.run_cycle(501, 1, 5001)  # car_body_id is still written: the same
            assert again["replayed"] and not again["request_mismatch"] and again["result_car_body_id"] == CAR_BODY
            await plc.write(recipe_id=1, part_id=5001, cycle_req_id=501, cycle_request=1, car_body_id=7)
            other = await plc.wait_cell(lambda c: c["done"] and c["replayed"], "replayed 501")
            assert other["request_mismatch"] and other["result_car_body_id"] == CAR_BODY
            await plc.write(cycle_request=0)
        finally:
            await plc.stop_heartbeat()
            client.close()
