"""The line PLC's faults on the whole simulated cell, driven by the PLC emulator over Modbus TCP.

- PLC heartbeat lost while the robot moves: Abort; the cycle record, the first-out stop reason and
  the PLC's `error_code` all say 1201; recovery with the documented commands from the PLC (its
  heartbeat back, then Clear, Reset, Start); the next cycle installs and no install is repeated.
- PLC heartbeat lost while the cell stands in Execute: Hold with 1201; Unhold once it beats again.
- Refusals the PLC can act on (9xx codes), stored under the request id, replayed after a restart.
- A request to another unit id: exception 11, no traceback.
- `cellctl serve` with its Modbus port taken: a clear message naming `[plc] port` and a non-zero
  exit within seconds, as with the REST port.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import socket
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import pytest
from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import ROOT, free_port, running_service, sim_config

from cellctl.cell.alarms import AlarmCode
from cellctl.cell.tags import PackMLCommand, PackMLState
from cellctl.config import CellConfig
from cellctl.plc.facade import PlcErrorCode
from cellctl.service.compose import Service
from cellctl.store import CycleState

pytestmark = pytest.mark.timeout(180)

HEARTBEAT_LOST = int(AlarmCode.PLC_HEARTBEAT_LOST)


@contextlib.asynccontextmanager
async def plc_for(service: Service, cfg: CellConfig) -> AsyncIterator[PlcClient]:
    client = AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1)  # type: ignore[attr-defined]
    assert await client.connect()
    plc = PlcClient(client, cfg.plc.float_word_order, unit_id=cfg.plc.unit_id)
    try:
        yield plc
    finally:
        await plc.stop_heartbeat()
        client.close()


async def until(what: str, check: Callable[[], bool], timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout_s} s: {what}")
        await asyncio.sleep(0.002)


async def to_execute(plc: PlcClient) -> None:
    for cmd in (PackMLCommand.CLEAR, PackMLCommand.RESET, PackMLCommand.START):
        ack = await plc.command(cmd)
        assert ack["cmd_result"] == 0, f"{cmd.name} refused: {ack}"
    assert PackMLState((await plc.read_cell())["state_current"]) is PackMLState.EXECUTE


async def prepare_calibration(service: Service) -> None:
    """Build the oracle calibration (it renders the corner template) before the first cycle, off the
    event loop: built inside the first cycle it stalls the loop for seconds (issue 15 item 9), and a
    stalled loop reads as a lost PLC heartbeat before the robot has moved."""
    await asyncio.to_thread(service.orchestrator.calibration.cycle_calibration)


def heartbeat_alarm_active(service: Service) -> bool:
    return any(a.code == AlarmCode.PLC_HEARTBEAT_LOST and a.active for a in service.orchestrator.alarms.current())


async def test_a_plc_heartbeat_lost_while_the_robot_moves_aborts_and_the_plc_reads_1201(tmp_path: Path) -> None:
    # sim.time_scale 0.3: the cycle's first move lasts about 3 s, far longer than the heartbeat timeout.
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005, "heartbeat_alarm": True, "heartbeat_timeout_s": 1.0},
                     sim={"time_scale": 0.3})  # fmt: skip
    async with running_service(tmp_path, cfg) as service, plc_for(service, cfg) as plc:
        orch = service.orchestrator
        await prepare_calibration(service)
        plc.start_heartbeat(0.05)
        await plc.wait_cell(lambda c: c["plc_heartbeat_ok"], "the cell sees the PLC heartbeat")
        await to_execute(plc)
        await plc.write(recipe_id=1, part_id=501, cycle_req_id=9001, cycle_request=1)
        await plc.wait_cell(lambda c: c["busy"] and c["cycle_ack_id"] == 9001, "busy with 9001")
        await until("the robot moves", lambda: orch.robot.moving, 30.0)
        await plc.stop_heartbeat()  # the PLC falls silent mid-move

        done = await plc.wait_cell(lambda c: c["done"] and c["result_req_id"] == 9001, "the result of 9001", 30.0)
        assert done["nok"] and not done["ok"] and not done["replayed"], done
        assert done["error_code"] == HEARTBEAT_LOST, done
        assert not done["plc_heartbeat_ok"]
        aborted = await plc.wait_cell(lambda c: c["state_current"] == PackMLState.ABORTED, "Aborted")
        assert aborted["stop_reason_id"] == HEARTBEAT_LOST and not aborted["ready"]
        stop = orch.alarms.stop_reason
        assert stop is not None and stop.code == AlarmCode.PLC_HEARTBEAT_LOST
        record = await service.store.cycle_for_key("plc", "9001")
        assert record is not None and record.state is CycleState.FAILED, record
        assert record.result["error_code"] == HEARTBEAT_LOST, (record.error, record.result)
        assert record.install_started_at is None
        codes = {a.code for a in orch.alarms.current()}
        assert AlarmCode.ROBOT_FAULT not in codes and AlarmCode.TASK_FAILED not in codes, codes
        assert not orch.robot.moving

        # Recovery from the PLC with the documented commands, without a restart.
        await plc.write(cycle_request=0)
        await plc.wait_cell(lambda c: not c["done"], "done cleared")
        plc.start_heartbeat(0.05)
        await plc.wait_cell(lambda c: c["plc_heartbeat_ok"], "the heartbeat back")
        await until("alarm 1201 cleared by its source", lambda: not heartbeat_alarm_active(service))
        await to_execute(plc)
        again = await plc.run_cycle(9001, 1, 501)  # the aborted id: its stored result, never a second run
        assert again["replayed"] and again["error_code"] == HEARTBEAT_LOST
        ok = await plc.run_cycle(9002, 1, 502, timeout_s=60.0)
        assert ok["ok"] and ok["error_code"] == 0 and not ok["replayed"], ok

        records = await service.store.cycles(limit=10)
        assert sorted(r.idempotency_key for r in records) == ["9001", "9002"]
        installed = [r.idempotency_key for r in records if r.install_started_at is not None]
        assert installed == ["9002"]


async def test_a_plc_heartbeat_lost_while_the_robot_stands_holds_and_unhold_resumes(tmp_path: Path) -> None:
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005, "heartbeat_alarm": True, "heartbeat_timeout_s": 2.0})
    async with running_service(tmp_path, cfg) as service, plc_for(service, cfg) as plc:
        await prepare_calibration(service)
        plc.start_heartbeat(0.05)
        await plc.wait_cell(lambda c: c["plc_heartbeat_ok"], "the cell sees the PLC heartbeat")
        await to_execute(plc)
        await plc.stop_heartbeat()
        held = await plc.wait_cell(lambda c: c["state_current"] == PackMLState.HELD, "Held", 10.0)
        assert held["stop_reason_id"] == HEARTBEAT_LOST and not held["plc_heartbeat_ok"] and not held["ready"]
        refused = await plc.command(PackMLCommand.UNHOLD)  # its cause is still there
        assert refused["cmd_result"] == 5  # blocked: the table allows it, the alarm holds it back (map 1.4)
        plc.start_heartbeat(0.05)
        await until("alarm 1201 cleared by its source", lambda: not heartbeat_alarm_active(service))
        assert (await plc.command(PackMLCommand.UNHOLD))["cmd_result"] == 0
        back = await plc.wait_cell(lambda c: c["state_current"] == PackMLState.EXECUTE and c["ready"], "Execute, ready")
        assert back["stop_reason_id"] == 0
        ok = await plc.run_cycle(9101, 1, 7, timeout_s=60.0)
        assert ok["ok"], ok


async def test_refusals_have_their_own_codes_are_stored_and_replayed_after_a_restart(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005})
    async with running_service(tmp_path, cfg) as service, plc_for(service, cfg) as plc:
        first = await plc.read_cell()
        assert first["state_current"] == PackMLState.ABORTED and not first["ready"]  # the cell starts in Aborted
        not_ready = await plc.run_cycle(801, 1, 5)
        assert not_ready["nok"] and not_ready["error_code"] == PlcErrorCode.NOT_READY and not not_ready["replayed"]
        await to_execute(plc)
        assert (await plc.read_cell())["ready"]
        again = await plc.run_cycle(801, 1, 5)  # the refusal is 801's result: not run now that the cell is ready
        assert again["replayed"] and again["error_code"] == PlcErrorCode.NOT_READY

        bad = await plc.run_cycle(802, 42, 5)
        assert bad["nok"] and bad["error_code"] == PlcErrorCode.UNKNOWN_RECIPE and not bad["replayed"]
        assert any("802" in r.getMessage() and "recipe_id 42" in r.getMessage() for r in caplog.records)
        bad_again = await plc.run_cycle(802, 1, 5)
        assert bad_again["replayed"] and bad_again["request_mismatch"] and bad_again["error_code"] == PlcErrorCode.UNKNOWN_RECIPE
        assert (bad_again["result_recipe_id"], bad_again["result_part_id"]) == (42, 5)

        other_unit = await plc.client.read_holding_registers(100, count=2, device_id=7)
        assert other_unit.isError() and other_unit.exception_code == 11
        assert await service.store.cycles(limit=10) == []  # nothing ran
    async with running_service(tmp_path, cfg) as service, plc_for(service, cfg) as plc:  # the same store
        await to_execute(plc)
        for req_id, code in ((801, PlcErrorCode.NOT_READY), (802, PlcErrorCode.UNKNOWN_RECIPE)):
            replay = await plc.run_cycle(req_id, 1, 5)
            assert replay["replayed"] and replay["nok"] and replay["error_code"] == code
        ok = await plc.run_cycle(803, 1, 5, timeout_s=60.0)
        assert ok["ok"] and not ok["replayed"]
        assert [r.idempotency_key for r in await service.store.cycles(limit=10)] == ["803"]
    noisy = [r for r in caplog.records if r.levelno >= logging.ERROR or r.exc_info]
    assert noisy == [], [r.getMessage() for r in noisy]


def test_cellctl_serve_exits_nonzero_naming_the_plc_port_when_it_is_taken(tmp_path: Path) -> None:
    with socket.socket() as other:  # another program listens on the Modbus port
        other.bind(("127.0.0.1", 0))
        other.listen()
        plc_port, api_port = other.getsockname()[1], free_port()
        text = (ROOT / "config" / "sim.toml").read_text()
        text, n_plc = re.subn(r"(?m)^port = 5020$", f"port = {plc_port}", text)
        text, n_api = re.subn(r"(?m)^port = 8080$", f"port = {api_port}", text)
        assert (n_plc, n_api) == (1, 1)
        config = tmp_path / "cell.toml"
        config.write_text(text)
        t0 = time.monotonic()
        proc = subprocess.run(
            [sys.executable, "-m", "cellctl.cli", "--config", str(config), "serve", "--workdir", str(tmp_path)],
            check=False, capture_output=True, text=True, timeout=60, cwd=tmp_path,
        )  # fmt: skip
        elapsed = time.monotonic() - t0
    assert proc.returncode != 0, (proc.returncode, proc.stdout, proc.stderr)
    assert elapsed < 20.0, elapsed
    assert "[plc] port" in proc.stderr and f"127.0.0.1:{plc_port}" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    with socket.socket() as probe:  # and it never served REST
        assert probe.connect_ex(("127.0.0.1", api_port)) != 0
