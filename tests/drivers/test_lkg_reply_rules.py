"""Reply rules of the LK-G codec no other test pinned down (a mutation run found them unguarded).

Facts (../shared/reference/keyence_lkg.md A1, A3, A6, A8, B4): a reply echoes the command's header;
``M1`` is answered by ``M1,<v>`` (one value), ``M0`` by ``M0,<v1>,<v2>``, ``MS,nn`` by ``MS,nn,<v>``,
``MM,<mask>`` by one value per OUT the mask selects; an error reply is ``ER,<main command>,<code>``,
and only for the setting commands (``SW``/``SR``) do some controllers head it with the setting's
identifier instead.
"""

from __future__ import annotations

from collections.abc import Callable

import pytest

from keyence_lkg.codec import Command, GarbledReply, LkgDialect, decode_values, dialect_for, may_answer, parse_line
from keyence_lkg.units import unit_format

FMT = unit_format("0.0001mm")


@pytest.mark.parametrize(
    ("dialect", "outs", "reply"),
    [
        ("LK-G3001", (1,), b"M1,+01.2345,-00.0120"),  # M1 answers one value
        ("LK-G3001", (1, 2), b"M0,+01.2345,-00.0120,+00.0001"),  # M0 answers two
        ("LK-G5001", (2,), b"MS,02,+01.2345,-00.0120"),  # MS,nn answers one
        ("LK-G5001", (1, 3), b"MM,101000000000,+01.2345,-00.0120,+00.0001"),  # two OUTs selected
    ],
)
def test_a_reply_with_more_values_than_the_command_asks_is_garbled(
    dialect: str, outs: tuple[int, ...], reply: bytes
) -> None:
    """An extra value means the reply is not the answer to this command (or a mis-framed line): it is
    dropped, never read as if its first values were the OUTs asked for."""
    d = dialect_for(dialect)
    command = d.read_output(outs[0]) if len(outs) == 1 else d.read_outputs(outs)[0]
    assert reply.startswith(command.text.encode() + b",")
    with pytest.raises(GarbledReply, match="value"):
        decode_values(command, parse_line(reply), FMT)


def test_the_exact_value_count_is_read() -> None:
    command, order = dialect_for("LK-G5001").read_outputs((3, 1))
    assert command.text == "MM,101000000000" and order == (1, 3)
    values = decode_values(command, parse_line(b"MM,101000000000,+01.2345,-00.0120"), FMT)
    assert [v.mm for v in values] == pytest.approx([1.2345, -0.012])


@pytest.mark.parametrize(
    ("dialect", "command_of", "error"),
    [
        ("LK-G5001", lambda d: d.read_output(1), b"ER,01,50"),  # MS,01: the OUT field is no header
        ("LK-G5001", lambda d: d.read_outputs((1, 2))[0], b"ER,110000000000,50"),  # MM,<mask>
        ("LK-G3001", lambda d: d.read_output(2), b"ER,2,00"),  # M2
    ],
)
def test_an_error_headed_by_a_measurement_parameter_answers_no_measurement(
    dialect: str, command_of: Callable[[LkgDialect], Command], error: bytes
) -> None:
    """MAN-135: ``ER,<main command>,<code>``. Only SW/SR errors may name their identifier (B4); an ER line
    whose head is a measurement command's parameter belongs to no measurement command."""
    command = command_of(dialect_for(dialect))
    assert command.main not in ("SW", "SR")
    assert not may_answer(command, parse_line(error))


def test_a_setting_error_may_name_the_main_command_or_the_setting() -> None:
    g5 = dialect_for("LK-G5001")
    sw = g5.write_setting("CF", "0001000", "09")
    assert may_answer(sw, parse_line(b"ER,SW,62"))
    assert may_answer(sw, parse_line(b"ER,CF,62"))
    assert not may_answer(sw, parse_line(b"ER,OK,62"))
