"""A new cycle_req_id written while cycle_request stays 1 is the next request: served after the running one.

The PLC side is pymodbus's client (plc_test_support.PlcClient); the cell is the tests' MemoryCell.
"""

from __future__ import annotations

import asyncio

from plc_test_support import MemoryCell, expected_wire, running_cell

from cellctl.cell.tags import CycleStep


async def test_a_new_id_written_while_a_cycle_runs_is_echoed_busy_then_done_after_it() -> None:
    gate = asyncio.Event()
    cell = MemoryCell(gate=gate)
    async with running_cell(cell) as (_server, plc):
        await plc.wait_cell(lambda c: c["ready"], "ready")
        await plc.write(recipe_id=1, part_id=2301, cycle_req_id=23, cycle_request=1)
        await plc.wait_cell(lambda c: c["busy"] and c["cycle_ack_id"] == 23 and c["cycle_step"] == CycleStep.INSTALL,
                            "busy with 23")
        # the PLC writes the next request's id (and its part) without dropping cycle_request
        await plc.write(recipe_id=2, part_id=2401, cycle_req_id=24, cycle_request=1)
        gate.set()
        busy24 = await plc.wait_cell(lambda c: c["cycle_ack_id"] == 24 and (c["busy"] or c["done"]), "24 echoed")
        assert not busy24["ready"]
        done24 = await plc.wait_cell(lambda c: c["done"] and c["cycle_ack_id"] == 24, "done for 24")
        assert done24["ok"] and done24["result_req_id"] == 24 and not done24["replayed"]
        assert (done24["result_part_id"], done24["result_recipe_id"]) == (2401, 2)
        for name, value in expected_wire(cell.outcomes[24]).items():
            assert done24[name] == value, name
        assert cell.started == [23, 24]  # both ran, one after the other, each once
        await plc.write(cycle_request=0)
        await plc.wait_cell(lambda c: c["ready"] and not c["done"], "ready again")
        # 23's result is not lost: repeating its id publishes it again, and runs nothing
        again = await plc.run_cycle(23, 1, 2301)
        assert again["replayed"] and again["result_req_id"] == 23 and again["ok"]
        assert again["dx_mm"] == expected_wire(cell.outcomes[23])["dx_mm"]
        assert cell.started == [23, 24]


async def test_a_new_id_written_at_done_before_the_drop_is_served_too() -> None:
    cell = MemoryCell()
    async with running_cell(cell) as (_server, plc):
        await plc.wait_cell(lambda c: c["ready"], "ready")
        await plc.write(recipe_id=1, part_id=31, cycle_req_id=31, cycle_request=1)
        await plc.wait_cell(lambda c: c["done"] and c["cycle_ack_id"] == 31, "done for 31")
        await plc.write(recipe_id=1, part_id=32, cycle_req_id=32, cycle_request=1)  # no drop in between
        done = await plc.wait_cell(lambda c: c["done"] and c["cycle_ack_id"] == 32, "done for 32")
        assert done["ok"] and done["result_req_id"] == 32 and done["result_part_id"] == 32
        assert cell.started == [31, 32]
        # a refused id behind it (unknown recipe) is answered the same way: done + nok with its code
        await plc.write(recipe_id=9, part_id=33, cycle_req_id=33, cycle_request=1)
        refused = await plc.wait_cell(lambda c: c["done"] and c["cycle_ack_id"] == 33, "done for 33")
        assert refused["nok"] and refused["error_code"] == 905 and cell.started == [31, 32]
        await plc.write(cycle_request=0)
        await plc.wait_cell(lambda c: c["ready"] and not c["done"], "ready again")
