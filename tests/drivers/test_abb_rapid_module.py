"""The RAPID modules agree with the Python protocol definition (they cannot run here)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from abb_robot import protocol as P

RAPID = Path(__file__).resolve().parents[2] / "drivers" / "abb_robot" / "rapid"
SERVER = (RAPID / "CellctlServer.mod").read_text(encoding="ascii")
MOTION = (RAPID / "CellctlMotion.mod").read_text(encoding="ascii")


def _consts(text: str, prefix: str) -> dict[str, float]:
    return {m[1]: float(m[2]) for m in re.finditer(rf"CONST num ({prefix}\w*):=(-?[\d.]+);", text)}


def _code(text: str) -> str:
    """The module without comments and string literals (for structure checks)."""
    text = re.sub(r'"[^"]*"', '""', text)
    return "\n".join(line.split("!")[0] for line in text.splitlines())


def test_error_codes_match_the_protocol() -> None:
    server = _consts(SERVER, "CELLCTL_E_")
    assert server == {f"CELLCTL_E_{c.name}": float(c) for c in P.ErrorCode}
    motion = _consts(MOTION, "CELLCTL_E_")
    for name, value in motion.items():
        if name != "CELLCTL_E_OK":
            assert server[name] == value, name


def test_protocol_version_and_command_kinds_match() -> None:
    assert _consts(SERVER, "CELLCTL_PROTOCOL") == {"CELLCTL_PROTOCOL": float(P.PROTOCOL_VERSION)}
    assert _consts(SERVER, "CMD_") == _consts(MOTION, "CMD_")


def test_every_verb_is_parsed_dispatched_and_has_the_right_arity() -> None:
    arity_fn = SERVER[SERVER.index("FUNC num Arity") : SERVER.index("ENDFUNC", SERVER.index("FUNC num Arity"))]
    arities: dict[str, int] = {}
    for m in re.finditer(r"CASE ([^:]+):\s*RETURN (-?\d+);", arity_fn):
        for verb in re.findall(r'"(\w+)"', m[1]):
            arities[verb] = int(m[2])
    assert arities == {name: len(v.args) for name, v in P.VERBS.items()}
    handle = SERVER[SERVER.index("FUNC bool HandleLine") :]
    for verb in P.VERBS:
        assert f'CASE "{verb}":' in handle, f"HandleLine does not dispatch {verb}"


def test_busy_rule_matches() -> None:
    fn = SERVER[SERVER.index("FUNC bool WhileMoving") :]
    fn = fn[: fn.index("ENDFUNC")]
    allowed = set(re.findall(r'"(\w+)"', fn))
    assert allowed == {name for name, v in P.VERBS.items() if v.while_moving}


def test_shared_persistents_are_declared_in_both_tasks() -> None:
    motion = dict(re.findall(r"PERS (\w+) (cellctl_\w+)(?:\{\d+\})?:=", MOTION))
    server = dict(re.findall(r"PERS (\w+) (cellctl_\w+)(?:\{\d+\})?;", SERVER))
    assert motion and {v: k for k, v in motion.items()} == {v: k for k, v in server.items()}


def test_blocks_are_balanced() -> None:
    for text in (SERVER, MOTION):
        code = _code(text)
        for opening, closing in (("PROC", "ENDPROC"), ("FUNC", "ENDFUNC"), ("TRAP", "ENDTRAP"),
                                 ("WHILE", "ENDWHILE"), ("TEST", "ENDTEST"), ("FOR", "ENDFOR"),
                                 ("MODULE", "ENDMODULE")):
            opens = len(re.findall(rf"^\s*(?:LOCAL\s+)?{opening}\b", code, re.M))
            closes = len(re.findall(rf"^\s*{closing}\b", code, re.M))
            assert opens == closes, f"{opening}/{closing}: {opens} vs {closes}"
        block_ifs = len(re.findall(r"^\s*IF\b.*\bTHEN\s*$", code, re.M))
        assert block_ifs == len(re.findall(r"^\s*ENDIF\b", code, re.M))


def test_every_reply_the_server_builds_fits_a_line() -> None:
    # Literal replies: "<id> " (6 chars at most) + the literal must fit 79 characters.
    for literal in re.findall(r'Reply\w* [\w{}]+,"([^"]*)"', SERVER):
        assert len("99999 ") + len(literal) <= 79, literal
    assert "StrPart(text,1,room)" in SERVER  # ReplyErr cuts its text to fit
    assert '\\0A' in SERVER  # lines end with a newline


def test_grip_sets_the_configured_output_waits_and_answers_as_the_fake_does() -> None:
    start = SERVER.index("PROC DoGrip")
    proc = _code(SERVER[start : SERVER.index("ENDPROC", start)])
    # The output is looked up by the configured name, switched, then the settle time is waited.
    steps = ["AliasIO grip_signal,grip_sig;", "SetDO grip_sig,arg{1};", "WaitTime grip_settle;", 'Reply id,""+NumToStr(arg{1},0);']
    positions = [proc.index(step) for step in steps]
    assert positions == sorted(positions)
    assert "CELLCTL_E_GRIPPER" in proc and "RAISE;" in proc  # I/O errors answered, socket errors passed on
    # Its settings are this task's own persistents, with values (not shared with the motion task).
    assert re.search(r'^\s*TASK PERS string grip_signal:="\w+";', SERVER, re.M)
    assert re.search(r"^\s*TASK PERS num grip_settle:=[\d.]+;", SERVER, re.M)
    assert re.search(r"^\s*VAR signaldo grip_sig;", SERVER, re.M)
    # The texts the fake answers with (tests/drivers/test_abb_gripper.py) are the module's.
    assert '"GRIP needs 0 (release) or 1 (hold)"' in SERVER
    assert '"hold is not an integer"' in SERVER
    with pytest.raises(P.ProtocolError, match="^hold is not an integer$"):
        P.parse_request("7 GRIP 1.0")
