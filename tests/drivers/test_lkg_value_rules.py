"""Rules of the LK-G measured-value format no other test pinned down (a mutation run found them unguarded).

The facts are the manual's (../shared/reference/keyence_lkg.md A5, C4): a value is exactly eight
characters, a sign and seven that include the decimal point, right aligned and zero padded
(``+1.2345`` on the display is ``+01.2345`` on the wire); the only other tokens are ``+FFFFFFF``,
``-FFFFFFF`` and ``XXXXXXXX``; anything else is a protocol error, never a reading.
"""

from __future__ import annotations

import pytest

from keyence_lkg.units import ValueFormatError, ValueKind, parse_value, unit_format


@pytest.mark.parametrize(
    ("unit", "display"),
    [
        ("0.0001mm", "+1.2345"),  # manual p. 5-6: sent as +01.2345
        ("0.0001mm", "-0.0120"),  # sent as -00.0120
        ("0.1um", "-1.2"),  # sent as -00001.2 (not even seven characters)
        ("0.001mm", "+12.345"),  # seven characters with the unit's three decimals
    ],
)
def test_a_value_without_its_zero_padding_is_refused(unit: str, display: str) -> None:
    """The display form (fewer than eight characters) is not the wire form: a cut-off reply, not a number."""
    with pytest.raises(ValueFormatError):
        parse_value(display, unit_format(unit))


def test_the_padded_form_of_the_same_values_is_read() -> None:
    assert parse_value("+01.2345", unit_format("0.0001mm")).mm == pytest.approx(1.2345)
    assert parse_value("+012.345", unit_format("0.001mm")).mm == pytest.approx(12.345)


@pytest.mark.parametrize("token", ["XXXXXXX", "XXXXXXXXX", "X0001.23", "XXXXXXX1", "X+01.234"])
def test_only_the_exact_no_value_token_means_no_value(token: str) -> None:
    """``XXXXXXXX`` (eight X) is the manual's "no value yet"; a token merely starting with X is garbage."""
    with pytest.raises(ValueFormatError):
        parse_value(token, unit_format("0.001mm"))


def test_the_no_value_token_itself() -> None:
    value = parse_value("XXXXXXXX", unit_format("0.001mm"))
    assert value.kind is ValueKind.NO_VALUE and value.mm is None
