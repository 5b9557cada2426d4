"""The line protocol codec (abb_robot.protocol) and the README generated from it."""

from __future__ import annotations

from pathlib import Path

import pytest

from abb_robot import protocol as P

README = Path(__file__).resolve().parents[2] / "drivers" / "abb_robot" / "README.md"


def test_request_round_trip_for_every_verb() -> None:
    samples: dict[str, tuple[object, ...]] = {
        "HELLO": (1,), "TOOL": ("tGripper_2",), "WOBJ": ("wobj0",), "SPEED": (250.5, 45.0), "ZONE": (0.0,),
        "POS": (-99999.0, 12345.678, 0.0), "ORI": (-0.7071068, 0.0, 0.7071068, -0.0000001),
        "EGM": (0.29, 0.33, 0.1), "GRIP": (1,), "STREAM": (1,),
    }
    for verb, spec in P.VERBS.items():
        args = samples.get(verb, ())
        assert len(args) == len(spec.args), verb
        data = P.format_request(99999, verb, *args)  # type: ignore[arg-type]
        assert len(data) <= P.MAX_LINE and data.endswith(b"\n")
        req = P.parse_request(P.decode_line(data))
        assert req.req_id == 99999 and req.verb == verb
        for got, want in zip(req.args, args):
            if isinstance(want, float):
                assert got == pytest.approx(want, abs=1e-7)
            else:
                assert got == want


def test_pose_lines_keep_seven_decimals_and_fit_80_bytes() -> None:
    data = P.format_request(99999, "ORI", -0.12345678, -0.98765432, -0.0000004, -0.5)
    assert data == b"99999 ORI -0.1234568 -0.9876543 -0.0000004 -0.5000000\n"
    longest = P.format_request(99999, "POS", -99999.0, -99999.0, -99999.0)
    assert len(longest) <= 80
    with pytest.raises(P.ProtocolError, match="99999 mm"):
        P.format_request(1, "POS", 100000.5, 0.0, 0.0)


def test_longest_replies_fit_80_bytes() -> None:
    pos = P.format_reply(99999, P.Status.DATA, "POS", *P.format_position_fields((-99999.999,) * 3))
    ori = P.format_reply(99999, P.Status.OK, "ORI", *P.format_quaternion_fields((-0.5, -0.5, -0.5, -0.5)))
    joints = P.format_reply(99999, P.Status.OK, *(P.format_num(-359.9999, P.JOINT_DECIMALS) for _ in range(6)))
    hello = P.format_reply(99999, P.Status.OK, "1", "X" * 28, "Y" * 28)
    for line in (pos, ori, joints, hello):
        assert len(line) <= P.MAX_LINE
    err = P.format_error(12, P.ErrorCode.REACH, "word " * 40)
    assert len(err) == P.MAX_LINE and err.startswith(b"12 ERR 130 word")


def test_negative_zero_is_not_sent() -> None:
    assert P.format_num(-0.0000001, 3) == "0.000"
    assert P.format_num(-1e-9, 7) == "0.0000000"


@pytest.mark.parametrize(
    ("line", "code", "rid"),
    [
        ("", P.ErrorCode.SYNTAX, 0),
        ("PING", P.ErrorCode.SYNTAX, 0),
        ("0 PING", P.ErrorCode.SYNTAX, 0),
        ("123456 PING", P.ErrorCode.SYNTAX, 0),
        ("+5 PING", P.ErrorCode.SYNTAX, 0),
        ("7", P.ErrorCode.SYNTAX, 7),
        ("7 JUMP", P.ErrorCode.SYNTAX, 7),
        ("7 PING now", P.ErrorCode.SYNTAX, 7),
        ("7 POS 1 2", P.ErrorCode.SYNTAX, 7),
        ("7 POS 1 2 1e3", P.ErrorCode.SYNTAX, 7),
        ("7 POS 1 2 x", P.ErrorCode.SYNTAX, 7),
        ("7 HELLO 1.0", P.ErrorCode.SYNTAX, 7),
        ("7 GRIP 1.0", P.ErrorCode.SYNTAX, 7),
        ("7 GRIP", P.ErrorCode.SYNTAX, 7),
        ("7 TOOL 9tool", P.ErrorCode.RANGE, 7),
        ("7\tPING", P.ErrorCode.SYNTAX, 0),
    ],
)
def test_malformed_requests_name_their_code(line: str, code: P.ErrorCode, rid: int) -> None:
    with pytest.raises(P.ProtocolError) as info:
        P.parse_request(line)
    assert info.value.code is code
    assert info.value.req_id == rid


def test_verbs_are_case_insensitive_and_spaces_collapse() -> None:
    req = P.parse_request("12   movel")
    assert (req.req_id, req.verb, req.args) == (12, "MOVEL", ())


def test_reply_parsing() -> None:
    r = P.parse_reply("17 ERR 130 target outside reach")
    assert r.req_id == 17 and r.status is P.Status.ERR
    assert r.error_code == 130 and r.error_text == "target outside reach"
    assert P.parse_reply("3 DATA POS 1.000 2.000 3.000").fields == ("POS", "1.000", "2.000", "3.000")
    assert P.parse_labelled(("ORI", "1", "0", "0", "0"), "ORI", 4) == (1.0, 0.0, 0.0, 0.0)
    for bad in ("garbage", "x OK", "5 MAYBE", "5 ERR", "5 ERR abc text"):
        with pytest.raises(P.ProtocolError):
            P.parse_reply(bad)
    with pytest.raises(P.ProtocolError):
        P.parse_labelled(("POS", "1", "2"), "POS", 3)
    with pytest.raises(P.ProtocolError, match="80-byte"):
        P.decode_line(b"1 OK " + b"9" * 80 + b"\n")
    with pytest.raises(P.ProtocolError, match="ASCII"):
        P.decode_line("1 OK \u00e9\n".encode())


def test_readme_table_is_generated_from_the_codec() -> None:
    text = README.read_text(encoding="utf-8")
    begin = text.index(P.TABLE_BEGIN) + len(P.TABLE_BEGIN) + 1
    end = text.index(P.TABLE_END)
    assert text[begin:end] == P.markdown_tables(), "README.md is stale: run python -m abb_robot.protocol_table"


def test_error_codes_have_descriptions() -> None:
    assert set(P.ERROR_DESCRIPTIONS) == set(P.ErrorCode)
    assert all(100 <= int(c) <= 999 for c in P.ErrorCode)
