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


def _routine(text: str, head: str) -> str:
    """One PROC, FUNC or TRAP of a module, from its head to its end."""
    start = text.index(head)
    end = min(text.index(word, start) for word in ("ENDPROC", "ENDFUNC", "ENDTRAP") if word in text[start:])
    return text[start:end]


def test_stream_runs_egm_position_stream_in_the_motion_task() -> None:
    assert "CASE CMD_STREAM:\n                RunStream;" in MOTION
    run = _routine(MOTION, "PROC RunStream")
    body, error = run.split("    ERROR\n")
    # A running stream is ended first (STREAM 1 restarts it at seqno 0); STREAM 0 only ends it.
    steps = ["IF cellctl_stream_on StopStream;", "IF cellctl_cmd_args{1}=0 THEN", "EGMGetId cellctl_stream_id;",
             "EGMSetupUC ROB_1,cellctl_stream_id,CELLCTL_EGM_PROFILE,CELLCTL_EGM_DEVICE\\Pose;",
             "EGMActPose cellctl_stream_id\\Tool:=cellctl_tool\\WObj:=cellctl_wobj,",  # the frame of MoveL and GETC
             "EGMStreamStart cellctl_stream_id\\SampleRate:=CELLCTL_EGM_STREAM_RATE;", "cellctl_stream_on:=TRUE;"]
    positions = [body.index(step) for step in steps]
    assert positions == sorted(positions)
    assert "EGMRunPose" not in body and "CommTimeout" not in body  # streaming only: the sensor sends nothing back
    assert "Report CELLCTL_E_EGM_SETUP" in error and "StopStream;" in error
    assert _consts(MOTION, "CELLCTL_EGM_STREAM_RATE") == {"CELLCTL_EGM_STREAM_RATE": float(P.STREAM_SAMPLE_MS)}
    stop = _routine(MOTION, "PROC StopStream")
    assert stop.index("cellctl_stream_on:=FALSE;") < stop.index("EGMStreamStop cellctl_stream_id;") \
        < stop.index("EGMReset cellctl_stream_id;") and "TRYNEXT;" in stop
    # A STOP (or the client's going away) ends the stream, with or without a motion to stop.
    trap = _routine(MOTION, "TRAP StopTrap")
    assert trap.index("IF cellctl_stream_on StopStream;") < trap.index("IF cellctl_cmd_seq=cellctl_done_seq THEN")
    assert "StopStream;" in _routine(MOTION, "PROC CellctlInit")  # none left over from before a restart
    assert "VAR egmident cellctl_stream_id;" in MOTION  # apart from the guidance session's identity


def test_server_hands_stream_over_ends_it_on_stop_bye_and_lost_link_and_refuses_egm_meanwhile() -> None:
    do = _routine(SERVER, "PROC DoStream")
    assert do.index('"STREAM needs 1 (start) or 0 (stop)"') < do.index("Forward id,CMD_STREAM;")
    assert "cellctl_cmd_args:=[arg{1},0,0];" in do
    finished = _routine(SERVER, "PROC ReportFinished")
    assert 'ELSEIF active_kind=CMD_STREAM THEN\n                Reply active_id,"OK "+NumToStr(cellctl_cmd_args{1},0);' \
        in finished
    stop = _routine(SERVER, "PROC DoStop")
    assert "IF Busy() OR cellctl_stream_on THEN" in stop and "cellctl_stop_seq:=cellctl_stop_seq+1;" in stop
    assert "IF Busy() was_moving:=\"1\";" in stop  # was_moving is about motions only
    gone = _routine(SERVER, "PROC StopIfBusy")  # BYE, idle timeout and a closed socket all come here
    assert "IF Busy() OR cellctl_stream_on THEN" in gone and "WaitUntil NOT Busy() AND NOT cellctl_stream_on" in gone
    client = _routine(SERVER, "PROC ServeClient")
    assert client.count("StopIfBusy;") == 3
    egm = _routine(SERVER, "PROC DoEgm")
    assert egm.index("IF cellctl_stream_on THEN") < egm.index("ReplyErr id,CELLCTL_E_BUSY,") < egm.index("Forward")
    # The texts the fake answers with (tests/drivers/test_abb_egm_stream.py) are the module's.
    assert '"EGM refused: a position stream runs"' in SERVER
    assert '"on is not an integer"' in SERVER
    with pytest.raises(P.ProtocolError, match="^on is not an integer$"):
        P.parse_request("7 STREAM 1.0")
    assert P.VERBS["STREAM"].args == (P.Arg("on", "int"),) and not P.VERBS["STREAM"].while_moving
