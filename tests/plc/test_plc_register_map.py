"""The register map, its codec, the generated docs and the PLC config checks."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError
from pymodbus.client import ModbusTcpClient

from cellctl.cell.packml import DEFAULT_MODE_CHANGE_STATES
from cellctl.cell.tags import PackMLState
from cellctl.config.cell import ProcessConfig
from cellctl.config.plc import PlcConfig
from cellctl.config.store import PackMLConfig
from cellctl.plc.codec import decode_block, decode_value, encode_block, encode_value
from cellctl.plc.register_doc import render_markdown
from cellctl.plc.register_map import (
    BLOCKS,
    CELL_BLOCK,
    PLC_BLOCK,
    PLC_ERROR_CODE_RANGE,
    PLC_ERROR_TEXT,
    STORED_REFUSALS,
    UNIT_ID_EXCEPTION,
    Access,
    Block,
    PlcErrorCode,
    Register,
    RegType,
    check_map,
    register,
)

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "plc_register_map.md"
PM = ModbusTcpClient  # pymodbus's converters, an independent reference for the word orders
F32 = ModbusTcpClient.DATATYPE.FLOAT32
U32 = ModbusTcpClient.DATATYPE.UINT32


def test_committed_docs_equal_the_generated_table() -> None:
    assert DOC.read_text(encoding="utf-8") == render_markdown(), (
        "docs/plc_register_map.md is stale: run python -m cellctl.plc --write docs/plc_register_map.md")


def test_the_docs_cli_checks_and_prints(tmp_path: Path) -> None:
    run = [sys.executable, "-m", "cellctl.plc"]
    assert subprocess.run(run + ["--check", str(DOC)], capture_output=True, timeout=60).returncode == 0
    stale = tmp_path / "map.md"
    stale.write_text("old\n")
    res = subprocess.run(run + ["--check", str(stale)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 1 and "--write" in res.stderr
    printed = subprocess.run(run, capture_output=True, text=True, timeout=60)
    assert printed.stdout == render_markdown()


def test_every_register_appears_in_the_docs_with_its_address() -> None:
    text = render_markdown()
    for block in BLOCKS:
        for reg in block.registers:
            addr = str(reg.address) if reg.words == 1 else f"{reg.address}-{reg.end - 1}"
            assert f"| {addr} | `{reg.name}` | {reg.type.label} |" in text


def test_the_blocks_are_apart_and_single_writer() -> None:
    check_map()
    assert PLC_BLOCK.access is Access.PLC_WRITES and CELL_BLOCK.access is Access.CELL_WRITES
    assert PLC_BLOCK.end <= CELL_BLOCK.start
    for block in BLOCKS:
        assert all(r.access is block.access for r in block.registers)
    assert register("cycle_req_id").type is RegType.UINT32
    with pytest.raises(KeyError, match="no register"):
        register("cycle_id")


@pytest.mark.parametrize("bad, message", [
    (Block("b", Access.PLC_WRITES, 0, 10, (Register("a", 0, RegType.UINT32, Access.PLC_WRITES, "", ""),
                                           Register("b", 1, RegType.UINT16, Access.PLC_WRITES, "", ""))),
     "overlaps a at address 1"),
    (Block("b", Access.PLC_WRITES, 0, 10, (Register("a", 9, RegType.FLOAT32, Access.PLC_WRITES, "", ""),)),
     "outside"),
    (Block("b", Access.PLC_WRITES, 0, 10, (Register("a", 0, RegType.UINT16, Access.CELL_WRITES, "", ""),)),
     "written by cell"),
    (Block("b", Access.PLC_WRITES, 0, 200, ()), "do not fit one Modbus request"),
])
def test_an_inconsistent_map_is_refused(bad: Block, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        check_map((bad,))


def test_known_float32_words_in_both_orders() -> None:
    dx = register("dx_mm")
    assert encode_value(dx, 12.5, "big") == [0x4148, 0x0000]  # ABCD
    assert encode_value(dx, 12.5, "little") == [0x0000, 0x4148]  # CDAB
    assert decode_value(dx, [0x0000, 0x4148], "little") == 12.5
    ack = register("cycle_ack_id")
    assert encode_value(ack, 0x12345678, "big") == [0x1234, 0x5678]
    assert encode_value(ack, 0x12345678, "little") == [0x5678, 0x1234]


@pytest.mark.parametrize("order", ["big", "little"])
def test_float32_and_uint32_round_trip_and_match_pymodbus(order: str) -> None:
    rng = np.random.default_rng(8)
    floats = np.concatenate([rng.normal(0, 50, 500), rng.uniform(-1e6, 1e6, 200),
                             [0.0, -0.0, 1e-38, -3.4e38, 3.4e38, 0.1, -179.999]])
    dx = register("dx_mm")
    for x in floats:
        words = encode_value(dx, float(x), order)
        assert words == PM.convert_to_registers(float(x), F32, word_order=order)
        back = decode_value(dx, words, order)
        assert back == float(np.float32(x))
        assert back == PM.convert_from_registers(words, F32, word_order=order)
    part = register("part_id")
    for n in [0, 1, 65535, 65536, 0xFFFF_FFFF, *rng.integers(0, 2**32, 200).tolist()]:
        words = encode_value(part, int(n), order)
        assert words == PM.convert_to_registers(int(n), U32, word_order=order)
        assert decode_value(part, words, order) == n


def test_whole_blocks_round_trip() -> None:
    values = {"dx_mm": -1.25, "cycle_ack_id": 4_000_000_000, "state_current": 6, "cycle_flags": 0b101}
    for order in ("big", "little"):
        regs = encode_block(CELL_BLOCK, values, order)
        assert len(regs) == CELL_BLOCK.size
        decoded = decode_block(CELL_BLOCK, regs, order)
        assert {k: decoded[k] for k in values} == values
        assert decoded["dy_mm"] == 0.0


@pytest.mark.parametrize("name, value, error, message", [
    ("dx_mm", float("nan"), ValueError, "not a finite float32"),
    ("dx_mm", 1e39, ValueError, "not a finite float32"),
    ("dx_mm", "1.0", TypeError, "not a number"),
    ("state_current", 65536, ValueError, "outside the uint16 range"),
    ("state_current", -1, ValueError, "outside the uint16 range"),
    ("state_current", 2.5, TypeError, "not an integer"),
    ("cycle_ack_id", 2**32, ValueError, "outside the uint32 range"),
])
def test_values_a_register_cannot_hold_are_refused(name: str, value: object, error: type, message: str) -> None:
    with pytest.raises(error, match=message):
        encode_value(register(name), value, "big")  # type: ignore[arg-type]


def test_bad_word_order_and_lengths_are_refused() -> None:
    with pytest.raises(ValueError, match="float_word_order"):
        encode_value(register("dx_mm"), 1.0, "middle")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="needs 2 registers"):
        decode_value(register("dx_mm"), [1], "big")
    with pytest.raises(ValueError, match="needs 32 registers"):
        decode_block(PLC_BLOCK, [0] * 31, "big")
    with pytest.raises(KeyError, match="not in the PLC block"):
        encode_block(PLC_BLOCK, {"dx_mm": 1.0}, "big")


def test_plc_config_refuses_periods_that_cannot_work() -> None:
    PlcConfig(port=0)  # 0 means any free port
    with pytest.raises(ValidationError, match="heartbeat_timeout_s"):
        PlcConfig(heartbeat_timeout_s=0.05, scan_period_s=0.02)
    with pytest.raises(ValidationError, match="cell_heartbeat_period_s"):
        PlcConfig(cell_heartbeat_period_s=0.01, scan_period_s=0.02)
    with pytest.raises(ValidationError, match="cycle_result_timeout_s"):
        PlcConfig(cycle_result_timeout_s=1.0, facade_timeout_s=5.0)
    with pytest.raises(ValidationError, match="float_word_order"):
        PlcConfig(float_word_order="cdab")


def test_the_docs_list_every_error_code_and_say_which_are_stored() -> None:
    text = render_markdown()
    for code in PlcErrorCode:
        stored = "yes" if code in STORED_REFUSALS else "no"
        assert f"| {code.value} | `{code.name.lower()}` | {stored} | {PLC_ERROR_TEXT[code]} |" in text
    assert all(c in PLC_ERROR_CODE_RANGE for c in PlcErrorCode)
    # the refusals a PLC can get for a request that never runs are 9xx codes of their own
    assert PlcErrorCode.UNKNOWN_RECIPE in STORED_REFUSALS and PlcErrorCode.NOT_READY in STORED_REFUSALS
    assert not {PlcErrorCode.CYCLE_REQ_ID_ZERO, PlcErrorCode.CELL_NO_ANSWER, PlcErrorCode.RESULT_TIMEOUT} & STORED_REFUSALS
    assert "repeating the id republishes the refusal" in text


def test_the_docs_list_the_recipe_numbers_and_where_they_are_defined() -> None:
    text = render_markdown()
    assert "[[process.recipes]]" in text
    for recipe in ProcessConfig().recipes:  # what a config without [[process.recipes]] has
        assert f"| {recipe.id} | `{recipe.name}` |" in text
    assert f"refused with `error_code` {int(PlcErrorCode.UNKNOWN_RECIPE)}" in text


def test_the_docs_say_how_the_cell_starts_when_ready_is_set_and_where_modes_change() -> None:
    text = " ".join(render_markdown().split())
    initial = PackMLState[PackMLConfig().initial_state.upper()]
    assert initial is PackMLState.ABORTED
    assert f"the cell is in **Aborted** (`state_current` = {int(PackMLState.ABORTED)};" in text
    assert "`ready` is 1 only in Execute (`state_current` = 6)" in text
    states = ", ".join(f"{s.title()} ({int(PackMLState[s.upper()])})"
                       for s in sorted(PackMLConfig().mode_change_states, key=lambda s: PackMLState[s.upper()]))
    assert f"`[packml] mode_change_states`, by default {states};" in text
    assert set(PackMLConfig().mode_change_states) == {s.name.lower() for s in DEFAULT_MODE_CHANGE_STATES}
    assert f"exception code {UNIT_ID_EXCEPTION} (gateway target device failed to respond)" in text
