"""The LK-G protocol codec: values, reply forms, commands and error codes of both dialects."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from keyence_lkg.codec import (
    Command,
    ErrorReply,
    GarbledReply,
    Reply,
    decode_values,
    dialect_for,
    may_answer,
    parse_line,
    payload_of,
)
from keyence_lkg.errors import ERROR_CODES, describe_error
from keyence_lkg.units import (
    DISPLAY_UNITS,
    ValueFormatError,
    ValueKind,
    format_setting_integer,
    format_value,
    parse_setting_integer,
    parse_value,
    unit_format,
)

# --- values --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("unit", "mm", "token"),
    [
        ("0.0001mm", 1.2345, "+01.2345"),  # the manual's examples (p. 5-6)
        ("0.0001mm", -0.0120, "-00.0120"),
        ("0.01mm", 1234.56, "+1234.56"),
        ("0.1um", -0.0012, "-00001.2"),
        ("0.001mm", 0.0, "+000.000"),
        ("0.00001mm", 9.99999, "+9.99999"),
        ("0.01um", -0.00125, "-0001.25"),
    ],
)
def test_values_are_formatted_as_the_manual_shows(unit: str, mm: float, token: str) -> None:
    fmt = unit_format(unit)
    assert format_value(mm, fmt) == token
    assert parse_value(token, fmt).mm == pytest.approx(mm, abs=fmt.resolution_mm / 2)


def test_special_tokens_are_kinds_not_numbers() -> None:
    fmt = unit_format("0.001mm")
    assert parse_value("+FFFFFFF", fmt).kind is ValueKind.OVER_RANGE_PLUS
    assert parse_value("-FFFFFFF", fmt).kind is ValueKind.OVER_RANGE_MINUS
    assert parse_value("XXXXXXXX", fmt).kind is ValueKind.NO_VALUE
    assert all(parse_value(t, fmt).mm is None for t in ("+FFFFFFF", "-FFFFFFF", "XXXXXXXX"))


@pytest.mark.parametrize(
    "token",
    [
        "+01.234", "+001.2345", "01.23456", "+01.23.5", "+0123456", "+FFFFFF", "-------", "--------",
        "+01,2345", " +1.2345", "+1.2345e",
    ],
)
def test_malformed_values_are_refused(token: str) -> None:
    with pytest.raises(ValueFormatError):
        parse_value(token, unit_format("0.0001mm"))


def test_a_value_in_another_display_unit_is_refused_naming_the_setting() -> None:
    with pytest.raises(ValueFormatError, match="display_unit.*0.0001mm"):
        parse_value("+01.2345", unit_format("0.001mm"))


def test_values_beyond_seven_characters_are_over_range() -> None:
    fmt = unit_format("0.00001mm")  # +-9.99999 mm
    assert format_value(10.0, fmt) == "+FFFFFFF"
    assert format_value(-10.0, fmt) == "-FFFFFFF"
    assert fmt.capacity_mm == pytest.approx(9.99999)


@settings(max_examples=300, deadline=None)
@given(unit=st.sampled_from(sorted(DISPLAY_UNITS)), fraction=st.floats(-1.0, 1.0))
def test_format_then_parse_is_exact_to_half_a_step(unit: str, fraction: float) -> None:
    fmt = unit_format(unit)
    mm = fraction * fmt.capacity_mm
    token = format_value(mm, fmt)
    assert len(token) == 8
    assert parse_value(token, fmt).mm == pytest.approx(mm, abs=fmt.resolution_mm / 2 + 1e-12)


def test_setting_integers() -> None:
    fmt = unit_format("0.001mm")
    assert format_setting_integer(1.5, fmt) == "+001500"
    assert format_setting_integer(-0.002, fmt) == "-000002"
    assert parse_setting_integer("-000002", fmt) == pytest.approx(-0.002)
    with pytest.raises(ValueFormatError):
        parse_setting_integer("+1.5000", fmt)
    with pytest.raises(ValueError, match="does not fit"):
        format_setting_integer(1000.0, fmt)


def test_unknown_display_unit_lists_the_choices() -> None:
    with pytest.raises(ValueError, match="0.01mm, 0.001mm"):
        unit_format("mm")


# --- lines ---------------------------------------------------------------------------------


def test_reply_forms() -> None:
    assert parse_line(b"M1,+01.2345") == Reply("M1,+01.2345", ("M1", "+01.2345"))
    assert parse_line(b"Q0") == Reply("Q0", ("Q0",))
    assert parse_line(b"ER,M1,01") == ErrorReply("M1", "01")
    assert parse_line(b"ER,sw,62") == ErrorReply("SW", "62")


@pytest.mark.parametrize(
    "line",
    [b"", b"\x00\xffM1,+01.2345", b"M1,+01.2345\n", b"ER,M1", b"ER,M1,1", b"ER,,01", b"ER,M1,01,2", b"M1,,+1", b"x" * 300],
)
def test_garbled_lines_are_refused(line: bytes) -> None:
    with pytest.raises(GarbledReply):
        parse_line(line)


def test_echo_matching_never_confuses_commands() -> None:
    g5 = dialect_for("LK-G5001")
    ms1, ms2 = g5.read_output(1), g5.read_output(2)
    assert may_answer(ms1, parse_line(b"MS,01,+000.260"))
    assert not may_answer(ms2, parse_line(b"MS,01,+000.260"))
    assert not may_answer(ms1, parse_line(b"MS,010,+000.260"))
    assert may_answer(ms2, parse_line(b"ER,MS,62"))  # an error names only the main command
    g3 = dialect_for("LK-G3001")
    assert not may_answer(g3.read_output(1), parse_line(b"M0,+01.2345,-00.0120"))
    assert not may_answer(g3.read_output(1), parse_line(b"ER,M2,01"))


def test_payload_shapes() -> None:
    g3 = dialect_for("LK-G3001")
    fmt = unit_format("0.0001mm")
    m0 = g3.read_outputs((1, 2))[0]
    values = decode_values(m0, parse_line(b"M0,+01.2345,-00.0120"), fmt)
    assert [v.mm for v in values] == pytest.approx([1.2345, -0.012])
    with pytest.raises(GarbledReply, match="2 value"):
        decode_values(m0, parse_line(b"M0,+01.2345"), fmt)
    with pytest.raises(GarbledReply):
        decode_values(g3.read_output(1), parse_line(b"M1,+01.23X5"), fmt)
    sw = g3.write_setting("CA", "3")
    assert payload_of(sw, parse_line(b"SW,CA")) == ()
    with pytest.raises(GarbledReply):
        payload_of(sw, parse_line(b"SW,CA,3"))
    sr = g3.read_setting("OF", "1")
    assert payload_of(sr, parse_line(b"SR,OF,1,+01.2345")) == ("+01.2345",)
    with pytest.raises(GarbledReply):
        payload_of(sr, parse_line(b"SR,OF,1"))


# --- commands ------------------------------------------------------------------------------


def test_lk_g3001_commands() -> None:
    g = dialect_for("LK-G3001")
    assert g.read_output(1).wire == b"M1\r"
    assert g.read_output(2).wire == b"M2\r"
    cmd, outs = g.read_outputs((2, 1))
    assert (cmd.wire, outs) == (b"M0\r", (1, 2))
    assert g.communication_mode().wire == b"Q0\r"
    assert g.general_mode().wire == b"R0\r"
    assert g.write_setting("oc", "1", "0", "4").wire == b"SW,OC,1,0,4\r"
    assert g.read_setting("HB", "1").echo == "SR,HB,1"
    assert g.status_error_code == "01"
    with pytest.raises(ValueError, match="1..2"):
        g.read_output(3)


def test_lk_g5001_commands() -> None:
    g = dialect_for("LK-G5001")
    assert g.read_output(1).wire == b"MS,01\r"
    assert g.read_output(12).wire == b"MS,12\r"
    cmd, outs = g.read_outputs((5, 2))
    assert (cmd.wire, outs, cmd.value_count) == (b"MM,010010000000\r", (2, 5), 2)
    assert g.read_all().wire == b"MA\r"  # type: ignore[attr-defined]
    assert g.status_error_code == "51"
    with pytest.raises(ValueError, match="1..12"):
        g.read_output(13)


def test_barriers_offer_a_read_with_another_main_command() -> None:
    for name in ("LK-G3001", "LK-G5001"):
        g = dialect_for(name)
        mains = {b.main for b in g.barrier_commands()}
        assert len(mains) == len(g.barrier_commands()) == 3


def test_bad_setting_arguments_are_refused_before_sending() -> None:
    g = dialect_for("LK-G3001")
    with pytest.raises(ValueError, match="identifier"):
        g.write_setting("C,A", "1")
    with pytest.raises(ValueError, match="parameter"):
        g.write_setting("CA", "1\r")
    with pytest.raises(ValueError, match="at least one"):
        g.write_setting("CA")


def test_the_dialect_is_never_guessed() -> None:
    with pytest.raises(ValueError, match="never guessed"):
        dialect_for("LK-G")
    assert isinstance(dialect_for("LK-G5001").read_output(1), Command)


# --- error codes ---------------------------------------------------------------------------


def test_error_tables_hold_each_dialects_codes() -> None:
    assert sorted(ERROR_CODES["LK-G3001"]) == ["00", "01", "20", "21", "22", "88", "99"]
    assert sorted(ERROR_CODES["LK-G5001"]) == ["50", "51", "60", "61", "62", "88", "99"]


def test_a_code_of_the_other_dialect_points_at_the_config() -> None:
    assert "status error" in describe_error("LK-G3001", "01")
    message = describe_error("LK-G3001", "51")
    assert "LK-G5001" in message and "devices.laser.dialect" in message
    assert "unknown" in describe_error("LK-G5001", "42")
