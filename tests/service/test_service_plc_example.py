"""examples/plc_client.py, as the README gives it to a line's PLC programmer, runs cycles on the simulated cell,
and its addresses (and those of examples/plc_handshake.st) are the register map's."""

from __future__ import annotations

import asyncio
import importlib.util
import re
import sys
from pathlib import Path
from types import ModuleType

import pytest
from service_test_support import running_service, sim_config

from cellctl.plc.register_map import CELL_BLOCK, register
from cellctl.store import CycleState

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "plc_client.py"
ST_PROGRAM = REPO / "examples" / "plc_handshake.st"
pytestmark = pytest.mark.timeout(180)


def _example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("plc_client_example", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


async def test_the_example_plc_brings_the_cell_to_execute_and_runs_two_cycles(tmp_path: Path) -> None:
    cfg = sim_config(plc={"port": 0, "scan_period_s": 0.005, "heartbeat_alarm": True, "heartbeat_timeout_s": 2.0})
    async with running_service(tmp_path, cfg) as service:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, str(EXAMPLE), "--port", str(service.plc_server.port), "--part", "4711",  # type: ignore[attr-defined]
            "--cycles", "2", "--req-id", "9100", "--heartbeat-period", "0.2",
            cwd=tmp_path, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
        )  # fmt: skip
        out, _ = await asyncio.wait_for(proc.communicate(), 150)
        text = out.decode()
        assert proc.returncode == 0, text
        assert "cell in Execute" in text, text
        records = await service.store.cycles(limit=5)
        assert sorted(r.idempotency_key for r in records) == ["9100", "9101"]
        assert all(r.state is CycleState.DONE for r in records)
        for r in records:
            assert f"cycle_req_id {r.idempotency_key} part {r.request.part_id}: OK" in text, text
        assert not [a for a in service.orchestrator.alarms.current() if a.active], "the example's heartbeat kept the link"


def test_the_python_example_uses_the_register_maps_addresses() -> None:
    ex = _example()
    assert (ex.PLC_HEARTBEAT, ex.CNTRL_CMD, ex.CMD_CHANGE_REQUEST) == tuple(
        register(n).address for n in ("plc_heartbeat", "cntrl_cmd", "cmd_change_request"))
    assert (ex.RECIPE_ID, ex.PART_ID, ex.CYCLE_REQ_ID, ex.CYCLE_REQUEST) == tuple(
        register(n).address for n in ("recipe_id", "part_id", "cycle_req_id", "cycle_request"))
    assert (ex.CELL_START, ex.CELL_SIZE) == (CELL_BLOCK.start, CELL_BLOCK.size)
    for table in (ex.CELL_UINT16, ex.CELL_UINT32, ex.CELL_FLOAT32):
        for name, address in table.items():
            assert register(name).address == address, name
    flags = register("cycle_flags")
    assert ex.FLAG_BITS == {bit.name: bit.index for bit in flags.bits}


def test_the_structured_text_program_uses_the_register_maps_addresses() -> None:
    """Every ``(* name @ address *)`` note of the ST program names a register of the map at that address,
    and every index into CellBlock or PlcBlock it uses is one of those addresses."""
    text = ST_PROGRAM.read_text()
    notes = re.findall(r"(\w+) @ (\d+)", text)
    assert len(notes) >= 20, notes
    for name, address in notes:
        assert register(name).address == int(address), (name, address)
    for index, name in re.findall(r"(\d+);\s*\(\* ?(\w+) @", text):
        reg = register(name)
        base = CELL_BLOCK.start if reg.address >= CELL_BLOCK.start else 0
        assert int(index) == reg.address - base, (name, index)
    # the six corrections and the six measured figures follow dx_mm and meas_dx_mm, two words each
    for first, names in (("dx_mm", ("dy_mm", "dz_mm", "drx_deg", "dry_deg", "drz_deg")),
                         ("meas_dx_mm", ("meas_dy_mm", "meas_dz_mm", "meas_drx_deg", "meas_dry_deg", "meas_drz_deg"))):
        for k, name in enumerate(names, start=1):
            assert register(name).address == register(first).address + 2 * k, name
    for name, bit in re.findall(r"BIT_(\w+)\s*:\s*INT\s*:=\s*(\d+);", text):
        assert {b.name: b.index for b in register("cycle_flags").bits}[name.lower()] == int(bit), name
