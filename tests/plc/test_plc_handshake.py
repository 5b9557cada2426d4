"""The cycle and command handshakes, driven by a PLC made with pymodbus's AsyncModbusTcpClient."""

from __future__ import annotations

import asyncio
import dataclasses

import pytest
from plc_test_support import (
    ERR_INSTALL_FAILED,
    ERR_UNKNOWN_RECIPE,
    MemoryCell,
    expected_wire,
    running_cell,
)

from cellctl.cell.tags import CycleStep, PackMLCommand, PackMLState, UnitMode
from cellctl.plc.facade import CellStatus, CommandReply, CycleAcceptance, CycleOutcome, PlcErrorCode
from cellctl.plc.register_map import MAP_VERSION

pytestmark = pytest.mark.timeout(30)


@pytest.mark.parametrize("word_order", ["big", "little"])
async def test_twenty_cycles_with_a_repeated_id_run_nineteen(word_order: str) -> None:
    ids = [5000 + 37 * k for k in range(19)]
    # the 11th handshake repeats the 5th id: it must publish the stored result, not run again
    sequence = ids[:10] + [ids[4]] + ids[10:]
    failing = frozenset({ids[7]})
    cell = MemoryCell(failing_ids=failing)
    async with running_cell(cell, float_word_order=word_order) as (_server, plc):
        plc.start_heartbeat(0.05)
        first = await plc.read_cell()
        assert (first["map_version_major"], first["map_version_minor"]) == MAP_VERSION
        seen: dict[int, dict] = {}
        for n, req_id in enumerate(sequence):
            recipe, part = 1 + n % 3, 7_000_000 + 1000 * n + 70_000  # part ids above 65535 test uint32
            repeat = req_id in seen
            if repeat:
                recipe, part = seen[req_id]["result_recipe_id"], seen[req_id]["result_part_id"]
            done = await plc.run_cycle(req_id, recipe, part)
            assert done["cycle_ack_id"] == req_id
            assert done["result_req_id"] == req_id
            assert done["done"] and not done["busy"] and not done["ready"]
            assert done["replayed"] is repeat and not done["request_mismatch"]
            outcome = cell.outcomes[req_id]
            assert done["ok"] is outcome.ok and done["nok"] is (not outcome.ok)
            for name, value in expected_wire(outcome).items():
                assert done[name] == value, (req_id, name)
            if not repeat:
                assert (done["result_part_id"], done["result_recipe_id"]) == (part, recipe)
                seen[req_id] = done
            else:  # the same result registers as the first time (status words are sampled per scan)
                sampled = {"cell_heartbeat", "state_current", "cycle_step", "cycle_flags", "replayed"}
                assert {k: v for k, v in done.items() if k not in sampled} == \
                       {k: v for k, v in seen[req_id].items() if k not in sampled}
        assert cell.started == ids  # 20 handshakes, 19 cycles, in request order
        assert [i for i, d in seen.items() if d["nok"]] == [ids[7]]
        assert seen[ids[7]]["error_code"] == ERR_INSTALL_FAILED
        assert [e for e, _ in cell.link_events] == ["restored"]  # the heartbeat came up once, never lost
        # the configured word order is really on the wire: the other order reads different floats
        other = "little" if word_order == "big" else "big"
        wrong = await plc.read_cell(word_order=other)
        right = await plc.read_cell()
        assert right["dx_mm"] == expected_wire(cell.outcomes[ids[-1]])["dx_mm"]
        assert wrong["dx_mm"] != right["dx_mm"]


async def test_busy_while_running_then_done() -> None:
    gate = asyncio.Event()
    cell = MemoryCell(gate=gate)
    async with running_cell(cell) as (_server, plc):
        ready = await plc.wait_cell(lambda c: c["ready"], "ready")
        assert ready["state_current"] == PackMLState.IDLE
        await plc.write(recipe_id=2, part_id=99, cycle_req_id=41, cycle_request=1)
        busy = await plc.wait_cell(lambda c: c["busy"] and c["cycle_step"] == CycleStep.INSTALL, "busy")
        assert busy["cycle_ack_id"] == 41 and not busy["done"] and not busy["ready"]
        assert busy["state_current"] == PackMLState.EXECUTE
        # dropping the request early does not cancel the cycle, and a repeat of the id while busy
        # does not start a second one
        await plc.write(cycle_request=0)
        await plc.write(cycle_request=1)
        await asyncio.sleep(0.05)
        assert cell.started == [41]
        gate.set()
        done = await plc.wait_cell(lambda c: c["done"], "done")
        assert done["ok"] and done["result_req_id"] == 41 and not done["replayed"]
        await plc.write(cycle_request=0)
        after = await plc.wait_cell(lambda c: c["ready"], "ready again")
        assert not after["done"] and after["result_req_id"] == 41  # the last result stays readable
        assert cell.started == [41]


async def test_repeated_id_after_a_server_restart_is_not_run_again() -> None:
    cell = MemoryCell()
    async with running_cell(cell) as (_server, plc):
        first = await plc.run_cycle(77, 1, 1234)
        assert first["ok"] and not first["replayed"]
    async with running_cell(cell) as (_server, plc):  # a new server, the same cell (its store)
        again = await plc.run_cycle(77, 1, 1234)
        assert again["replayed"] and again["dx_mm"] == first["dx_mm"]
        mismatch = await plc.run_cycle(77, 2, 4321)
        assert mismatch["replayed"] and mismatch["request_mismatch"]
        assert (mismatch["result_part_id"], mismatch["result_recipe_id"]) == (1234, 1)
    assert cell.started == [77]


async def test_refused_requests_say_why_and_a_repeated_refused_id_replays_the_refusal() -> None:
    cell = MemoryCell()
    async with running_cell(cell) as (_server, plc):
        zero = await plc.run_cycle(0, 1, 5)
        assert zero["nok"] and zero["error_code"] == PlcErrorCode.CYCLE_REQ_ID_ZERO and not zero["replayed"]
        zero = await plc.run_cycle(0, 1, 5)  # 0 is not an id: nothing is stored under it
        assert zero["error_code"] == PlcErrorCode.CYCLE_REQ_ID_ZERO and not zero["replayed"]

        bad_recipe = await plc.run_cycle(12, 9, 5)
        assert bad_recipe["nok"] and bad_recipe["error_code"] == ERR_UNKNOWN_RECIPE == PlcErrorCode.UNKNOWN_RECIPE
        assert bad_recipe["cycle_ack_id"] == bad_recipe["result_req_id"] == 12 and not bad_recipe["replayed"]
        assert (bad_recipe["result_recipe_id"], bad_recipe["result_part_id"]) == (9, 5)
        # The refusal is the id's result: repeating the id republishes it, even with a valid recipe now.
        again = await plc.run_cycle(12, 9, 5)
        assert again["nok"] and again["error_code"] == ERR_UNKNOWN_RECIPE and again["replayed"]
        assert not again["request_mismatch"]
        other = await plc.run_cycle(12, 1, 5)
        assert other["replayed"] and other["request_mismatch"] and other["error_code"] == ERR_UNKNOWN_RECIPE
        assert (other["result_recipe_id"], other["result_part_id"]) == (9, 5)  # the stored refusal stands
        assert cell.started == [] and cell.refused == [12]  # asked the cell once
        ok = await plc.run_cycle(13, 1, 5)  # a new id runs
        assert ok["ok"] and cell.started == [13]

        # Not ready (the cell stopped): refused with its own code, stored the same way.
        cell.state = PackMLState.STOPPED
        await plc.wait_cell(lambda c: c["state_current"] == PackMLState.STOPPED and not c["ready"], "Stopped")
        stopped = await plc.run_cycle(14, 1, 6)
        assert stopped["nok"] and stopped["error_code"] == PlcErrorCode.NOT_READY and not stopped["replayed"]
        cell.state = PackMLState.IDLE
        await plc.wait_cell(lambda c: c["ready"], "ready again")
        again = await plc.run_cycle(14, 1, 6)
        assert again["replayed"] and again["error_code"] == PlcErrorCode.NOT_READY
        assert cell.started == [13]


async def test_refusals_are_replayed_by_the_interface_even_when_the_cell_does_not_store_them() -> None:
    cell = MemoryCell(store_refusals=False)
    async with running_cell(cell) as (_server, plc):
        first = await plc.run_cycle(21, 7, 3)
        assert first["error_code"] == ERR_UNKNOWN_RECIPE and not first["replayed"]
        again = await plc.run_cycle(21, 1, 3)
        assert again["replayed"] and again["request_mismatch"] and again["error_code"] == ERR_UNKNOWN_RECIPE
        assert cell.refused == [21] and cell.started == []


async def test_a_refusal_stored_by_the_cell_is_replayed_after_a_server_restart() -> None:
    cell = MemoryCell()
    async with running_cell(cell) as (_server, plc):
        assert (await plc.run_cycle(31, 8, 3))["error_code"] == ERR_UNKNOWN_RECIPE
    async with running_cell(cell) as (_server, plc):  # a new server, the same cell (its store)
        again = await plc.run_cycle(31, 8, 3)
        assert again["replayed"] and again["nok"] and again["error_code"] == ERR_UNKNOWN_RECIPE
    assert cell.refused == [31] and cell.started == []


class _SilentCell(MemoryCell):
    async def start_cycle(self, req_id: int, recipe_id: int, part_id: int) -> CycleAcceptance:
        await asyncio.sleep(3600)
        raise AssertionError("unreachable")


async def test_a_cell_that_does_not_answer_gives_nok_not_a_hang() -> None:
    cell = _SilentCell()
    async with running_cell(cell, facade_timeout_s=0.2, cycle_result_timeout_s=1.0) as (_server, plc):
        done = await plc.run_cycle(3, 1, 5)
        assert done["nok"] and done["error_code"] == PlcErrorCode.CELL_NO_ANSWER
        # not a result: repeating the id asks the cell again (and is not marked replayed)
        again = await plc.run_cycle(3, 1, 5)
        assert again["error_code"] == PlcErrorCode.CELL_NO_ANSWER and not again["replayed"]


class _NeverFinishingCell(MemoryCell):
    async def start_cycle(self, req_id: int, recipe_id: int, part_id: int) -> CycleAcceptance:
        self.started.append(req_id)
        return CycleAcceptance(True)

    async def result_of(self, req_id: int) -> CycleOutcome | None:
        return None


async def test_no_result_within_the_cycle_timeout_gives_nok() -> None:
    cell = _NeverFinishingCell()
    async with running_cell(cell, facade_timeout_s=0.1, cycle_result_timeout_s=0.3) as (_server, plc):
        done = await plc.run_cycle(8, 1, 5)
        assert done["nok"] and done["error_code"] == PlcErrorCode.RESULT_TIMEOUT


class _ConfusedCell(MemoryCell):
    """Answers with results the register map cannot carry, or that belong to another id."""

    async def result_of(self, req_id: int) -> CycleOutcome | None:
        o = self.outcomes.get(req_id)
        if o is None:
            return None
        if req_id == 2:
            return dataclasses.replace(o, req_id=999)
        return dataclasses.replace(o, dx_mm=1e39)  # finite, but beyond float32


async def test_answers_the_map_cannot_carry_give_nok_and_the_interface_survives() -> None:
    cell = _ConfusedCell()
    async with running_cell(cell) as (server, plc):
        wrong_id = await plc.run_cycle(2, 1, 5)
        assert wrong_id["nok"] and wrong_id["error_code"] == PlcErrorCode.CELL_BAD_ANSWER
        too_big = await plc.run_cycle(3, 1, 5)
        assert too_big["nok"] and too_big["error_code"] == PlcErrorCode.CELL_BAD_ANSWER
        again = await plc.run_cycle(3, 1, 5)
        assert again["nok"] and again["error_code"] == PlcErrorCode.CELL_BAD_ANSWER
        assert cell.started == [2, 3] and server.fault is None


async def test_packml_commands_and_unit_mode_through_the_latch() -> None:
    cell = MemoryCell()
    async with running_cell(cell) as (_server, plc):
        async def send(cmd: int) -> dict:
            await plc.write(cntrl_cmd=cmd, cmd_change_request=1)
            acked = await plc.wait_cell(lambda c: c["cmd_ack"] == 1, f"cmd_ack for {cmd}")
            await plc.write(cmd_change_request=0)
            await plc.wait_cell(lambda c: c["cmd_ack"] == 0, "cmd_ack cleared")
            return acked

        stop = await send(PackMLCommand.STOP)
        assert (stop["cmd_ack_cmd"], stop["cmd_result"]) == (PackMLCommand.STOP, CommandReply.ACCEPTED)
        await plc.wait_cell(lambda c: c["state_current"] == PackMLState.STOPPED, "Stopped")
        start = await send(PackMLCommand.START)
        assert start["cmd_result"] == CommandReply.INVALID_IN_STATE
        assert (await send(99))["cmd_result"] == CommandReply.BAD_PARAMETER
        assert (await send(PackMLCommand.UNDEFINED))["cmd_result"] == CommandReply.BAD_PARAMETER
        assert cell.commands == [PackMLCommand.STOP, PackMLCommand.START]

        await plc.write(unit_mode_request=UnitMode.MAINTENANCE, unit_mode_change_request=1)
        acked = await plc.wait_cell(lambda c: c["unit_mode_ack"] == 1, "unit_mode_ack")
        assert (acked["unit_mode_ack_mode"], acked["unit_mode_result"]) == (UnitMode.MAINTENANCE, 0)
        await plc.write(unit_mode_change_request=0)
        cleared = await plc.wait_cell(lambda c: c["unit_mode_ack"] == 0, "unit_mode_ack cleared")
        assert cleared["unit_mode_current"] == UnitMode.MAINTENANCE

        reset = await send(PackMLCommand.RESET)
        assert reset["cmd_result"] == CommandReply.ACCEPTED
        await plc.wait_cell(lambda c: c["state_current"] == PackMLState.IDLE and c["ready"], "Idle, ready")


def test_facade_values_refuse_inconsistent_input() -> None:
    with pytest.raises(ValueError, match="error_code"):
        CycleOutcome(req_id=1, recipe_id=1, part_id=1, ok=True, error_code=5, dx_mm=0, dy_mm=0,
                     dz_mm=0, drx_rad=0, dry_rad=0, drz_rad=0, cycle_time_s=1)
    with pytest.raises(ValueError, match="dy_mm must be a finite number"):
        CycleOutcome(req_id=1, recipe_id=1, part_id=1, ok=True, error_code=0, dx_mm=0,
                     dy_mm=float("nan"), dz_mm=0, drx_rad=0, dry_rad=0, drz_rad=0, cycle_time_s=1)
    with pytest.raises(ValueError, match="req_id must be nonzero"):
        CycleOutcome(req_id=0, recipe_id=1, part_id=1, ok=True, error_code=0, dx_mm=0, dy_mm=0,
                     dz_mm=0, drx_rad=0, dry_rad=0, drz_rad=0, cycle_time_s=1)
    with pytest.raises(ValueError, match="nonzero error_code"):
        CycleAcceptance(False)
    with pytest.raises(ValueError, match="stop_reason_id"):
        CellStatus(PackMLState.IDLE, UnitMode.PRODUCTION, CycleStep.NONE, -1, True)


class _MixedUpCell(MemoryCell):
    """Answers result_of with the newest result it has, whatever id was asked."""

    async def result_of(self, req_id: int) -> CycleOutcome | None:
        return next(reversed(self.outcomes.values()), None)


async def test_a_stored_result_under_another_id_is_a_bad_answer_and_starts_nothing() -> None:
    cell = _MixedUpCell()
    async with running_cell(cell) as (_server, plc):
        assert (await plc.run_cycle(5, 1, 3))["error_code"] == 0
        mixed = await plc.run_cycle(6, 1, 4)  # the cell answers result_of(6) with cycle 5's result
        assert mixed["nok"] and mixed["error_code"] == PlcErrorCode.CELL_BAD_ANSWER and not mixed["replayed"]
        assert cell.started == [5]


class _ResultOnceCell(MemoryCell):
    """Gives each result once: a cell that does not keep them (the interface's own memory must)."""

    async def result_of(self, req_id: int) -> CycleOutcome | None:
        return self.outcomes.pop(req_id, None)


async def test_a_result_the_cell_did_not_keep_is_replayed_from_the_interfaces_memory_not_run_again() -> None:
    cell = _ResultOnceCell()
    async with running_cell(cell) as (_server, plc):
        first = await plc.run_cycle(7, 2, 9)
        assert first["error_code"] == 0 and not first["replayed"]
        again = await plc.run_cycle(7, 2, 9)
        assert again["replayed"] and again["error_code"] == 0 and not again["request_mismatch"]
        assert cell.started == [7]


class _OnceSilentCell(MemoryCell):
    """Does not answer the second result_of in time (a moment's stall), then answers as usual."""

    def __init__(self) -> None:
        super().__init__()
        self.asked = 0

    async def result_of(self, req_id: int) -> CycleOutcome | None:
        self.asked += 1
        if self.asked == 2:
            await asyncio.sleep(1.0)
        return await super().result_of(req_id)


async def test_a_result_query_the_cell_misses_once_is_asked_again_until_the_cycle_timeout() -> None:
    cell = _OnceSilentCell()
    async with running_cell(cell, facade_timeout_s=0.2, cycle_result_timeout_s=10.0) as (_server, plc):
        done = await plc.run_cycle(8, 1, 2)
        assert done["error_code"] == 0 and not done["nok"] and cell.asked >= 3
        assert cell.started == [8]
