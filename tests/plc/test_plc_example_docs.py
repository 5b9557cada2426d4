"""The PLC examples against what docs/plc_register_map.md (generated) says: every cmd_result code, the error_codes
that are no result ("Stored: no", asked again), car_body_id written with each request; and docs/traceability.md
naming every `source` a cycle record can carry (each CycleRequest(..., source=...) in src/cellctl)."""

from __future__ import annotations

import importlib
import importlib.util
import re
from pathlib import Path
from types import ModuleType

from plc_test_support import MemoryCell, running_cell

from cellctl.plc.register_doc import render_markdown

REPO = Path(__file__).resolve().parents[2]
DOC = render_markdown()
ST = (REPO / "examples" / "plc_handshake.st").read_text()
TRACEABILITY = (REPO / "docs" / "traceability.md").read_text()


def _example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("plc_client_example", REPO / "examples" / "plc_client.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _doc_table(heading: str) -> list[list[str]]:
    """The rows of the first table after ``heading`` in the register map (cells stripped, backticks removed)."""
    tail = DOC[DOC.index(heading):]
    rows = []
    for line in tail.split("\n")[1:]:
        if rows and not line.startswith("|"):
            break
        if line.startswith("|") and not line.startswith("|---"):
            rows.append([c.strip().strip("`") for c in line.strip("|").split("|")])
    return rows[1:]


def test_both_examples_know_every_cmd_result_of_the_register_map() -> None:
    codes = {int(r[0]): r[1].replace("_", " ") for r in _doc_table("`cmd_result` and `unit_mode_result`:")}
    assert codes[5] == "blocked", codes
    assert _example().CMD_RESULTS == codes
    comment = re.search(r"CommandResult : UINT;\s*\(\*(.*?)\*\)", ST)
    assert comment is not None
    assert dict((int(n), text.strip()) for n, text in re.findall(r"(\d+) ([a-z ]+)", comment.group(1))) == codes


def test_the_examples_ask_again_for_exactly_the_codes_that_are_no_result() -> None:
    rows = _doc_table("`error_code` values of the PLC interface itself")
    not_stored = {int(r[0]): r[1] for r in rows if r[2] == "no"}
    assert sorted(not_stored) == [901, 902, 903, 904], rows
    assert _example().NOT_RESULTS == not_stored
    asked = re.search(r"IF AnswerCode >= (\d+) AND AnswerCode <= (\d+) THEN(.*?)ELSE", ST, re.S)
    assert asked is not None, "FB_CellHandshake step 10 should tell 901..904 apart from a result"
    assert set(range(int(asked.group(1)), int(asked.group(2)) + 1)) == set(not_stored)
    branch = re.sub(r"\(\*.*?\*\)", "", asked.group(3), flags=re.S)  # the code, not its comments
    assert "PlcBlock[P_CYCLE_REQUEST] := 0;" in branch and "InFlight := FALSE" not in branch
    assert "CycleDone" not in branch  # the car body waits for the real result


async def test_the_python_example_writes_car_body_id_so_no_stale_value_goes_with_its_request() -> None:
    ex = _example()
    cell = MemoryCell()
    async with running_cell(cell) as (_server, peer):
        await peer.write(car_body_id=4242)  # what an earlier client left in registers 11-12
        plc = ex.Plc(peer.client, 1, "big", 5.0)
        done = await plc.cycle(71, 1, 7100, 5.0)
        assert done["ok"] and cell.started == [71]
        block = await peer.read_plc_block()  # pymodbus FC3 of the PLC block: what the request carried
        assert block[11:13] == [0, 0], block[:13]
        await plc.cycle(72, 1, 7200, 5.0, car_body_id=0x12345)
        block = await peer.read_plc_block()
        assert block[11:13] == [0x1, 0x2345]  # uint32, high word first ([plc] float_word_order = "big")


def test_the_traceability_page_names_every_source_a_cycle_can_record() -> None:
    src = REPO / "src"
    sources = set()
    for path in (src / "cellctl").rglob("*.py"):
        for call in re.findall(r"CycleRequest\((?:[^()]|\([^()]*\))*\)", path.read_text()):
            m = re.search(r"source=(?:f?\"([^\"{]*)|([A-Z_][A-Z0-9_]*)\b(?![\[.(]))", call)
            if m is None:  # passed through (a stored record's source): not a value of its own
                continue
            if m.group(2):  # a module constant: its value as the module has it
                module = importlib.import_module(".".join(path.relative_to(src).with_suffix("").parts))
                sources.add(getattr(module, m.group(2)))
            else:
                sources.add(m.group(1).replace("rest:", "rest:<address>"))
    assert {"rest:<address>", "plc", "opcua"} <= sources, sources
    row = next(line for line in TRACEABILITY.split("\n") if line.startswith("| `cycle_id`"))
    named = set(re.findall(r"`([^`]+)`", row))
    assert sources <= named, f"docs/traceability.md does not name {sorted(sources - named)}"
