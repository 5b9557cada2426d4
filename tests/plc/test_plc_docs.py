"""What docs/plc_register_map.md (generated) and examples/plc_handshake.st tell a PLC programmer, against what
the cell does: recipes of config/sim.toml (read with tomllib), reserved PLC-block addresses, one writer, and the
restart recovery (a pymodbus PLC that restarts mid-cycle asks for the same id again and reads its result)."""

from __future__ import annotations

import asyncio
import re
import tomllib
from pathlib import Path

from plc_test_support import MemoryCell, expected_wire, running_cell

from cellctl.cell.tags import CycleStep
from cellctl.plc.register_doc import render_markdown
from cellctl.plc.register_map import PLC_BLOCK

REPO = Path(__file__).resolve().parents[2]
DOC = render_markdown()
ST = (REPO / "examples" / "plc_handshake.st").read_text()


def test_the_docs_do_not_say_the_sim_config_has_no_recipes() -> None:
    recipes = tomllib.loads((REPO / "config" / "sim.toml").read_text())["process"]["recipes"]
    assert "(such as `config/sim.toml`)" not in DOC
    named = re.search(r"`config/sim\.toml` lists its own: ([^)]*)\)", DOC)
    assert named is not None, "the docs should name the simulated cell's recipes"
    assert named.group(1) == " and ".join(f"{r['id']} {r['name']}" for r in recipes)


async def test_reserved_plc_block_addresses_are_documented_as_kept_and_not_read() -> None:
    assert "Reserved addresses inside a block read 0." not in DOC
    assert "Reserved addresses of the PLC block are not read by" in DOC and "write 0 to them" in DOC
    used = {a for r in PLC_BLOCK.registers for a in range(r.address, r.end)}
    reserved = [a for a in range(PLC_BLOCK.start, PLC_BLOCK.end) if a not in used]
    cell = MemoryCell()
    async with running_cell(cell) as (_server, plc):
        wr = await plc.client.write_registers(reserved[0], [0xFFFF] * len(reserved), device_id=1)
        assert not wr.isError()
        done = await plc.run_cycle(61, 1, 6100)  # whatever the reserved words hold, the cell does not read them
        assert done["ok"] and cell.started == [61]
        block = await plc.read_plc_block()
        assert [block[a] for a in reserved] == [0xFFFF] * len(reserved)  # kept, as the docs now say


def test_the_docs_say_one_client_writes_the_plc_block() -> None:
    flat = " ".join(DOC.split())
    assert "One client writes it: the line PLC" in flat
    assert "must only read (FC3)" in flat and "`[plc] allowed_clients` restricts by address" in flat


def test_the_docs_and_the_st_example_keep_the_id_in_flight_across_a_restart() -> None:
    flat = " ".join(DOC.split())
    assert "**A PLC that restarts.**" in flat and "request the **same** id again" in flat
    assert "Never give the same car body a new id" in flat
    retain = re.search(r"VAR RETAIN(.*?)END_VAR", ST, re.S)
    assert retain is not None and re.search(r"\bReqId\b", retain.group(1)) and re.search(r"\bInFlight\b", retain.group(1))
    assert "IF InFlight AND CellAlive AND NOT CycleTimer.Q THEN" in ST  # step 0 asks for the retained id again first
    assert re.search(r"WaitRobotClear AND \(Cell\.RobotClear", ST)  # the car body moves on only once robot_clear = 1


async def test_a_plc_restarting_mid_cycle_reads_the_result_by_asking_for_the_same_id() -> None:
    """What the docs tell a restarted PLC to do works: the cycle is not run twice and its result is the one stored."""
    gate = asyncio.Event()
    cell = MemoryCell(gate=gate)
    async with running_cell(cell) as (_server, plc):
        await plc.wait_cell(lambda c: c["ready"], "ready")
        await plc.write(recipe_id=1, part_id=4100, cycle_req_id=41, cycle_request=1, car_body_id=9041)
        await plc.wait_cell(lambda c: c["busy"] and c["cycle_step"] == CycleStep.INSTALL, "busy with 41")
        await plc.client.write_registers(0, [0] * 13, device_id=1)  # the PLC restarts: its block image is zeros
        gate.set()
        await plc.wait_cell(lambda c: 41 in cell.outcomes and not c["busy"] and not c["done"], "41 ended unseen")
        again = await plc.run_cycle(41, 1, 4100)  # car_body_id is 0 now: the PLC wrote zeros; the stored one stands
        assert again["replayed"] and again["result_req_id"] == 41 and again["ok"]
        assert again["dx_mm"] == expected_wire(cell.outcomes[41])["dx_mm"]
        assert cell.started == [41]
