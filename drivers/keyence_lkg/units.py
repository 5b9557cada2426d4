"""Measured values on the wire: sign plus seven characters, in the controller's display unit.

A value is 8 characters: ``+`` or ``-`` and seven digits including the decimal point, right
aligned and zero padded (manual p. 5-6: ``+1.2345`` is sent as ``+01.2345``). The unit is not in
the reply: it is the controller's "minimum display unit" setting, which fixes both the scale
(mm or um) and the number of decimals. The special values are ``+FFFFFFF`` / ``-FFFFFFF`` (over
range) and ``XXXXXXXX`` (no value yet).
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass
from typing import Final, Literal, Mapping

DisplayUnit = Literal["0.01mm", "0.001mm", "0.0001mm", "0.00001mm", "0.1um", "0.01um"]

OVER_RANGE_PLUS: Final = "+FFFFFFF"
OVER_RANGE_MINUS: Final = "-FFFFFFF"
NO_VALUE: Final = "XXXXXXXX"

_VALUE_RE: Final = re.compile(r"[+-][0-9.]{7}")


@dataclass(frozen=True)
class UnitFormat:
    """One minimum-display-unit setting: decimals on the wire and millimetres per wire unit."""

    name: DisplayUnit
    decimals: int
    mm_per_unit: float  # 1.0 when the wire value is in mm, 0.001 when it is in um

    @property
    def resolution_mm(self) -> float:
        """The smallest step of a value, in mm."""
        return self.mm_per_unit * 10.0**-self.decimals

    @property
    def capacity_mm(self) -> float:
        """The largest magnitude the 7 characters can show, in mm."""
        digits = 6  # seven characters minus the decimal point
        return (10.0**digits - 1) * self.resolution_mm


# LK-G3000 panel function G (G-0 .. G-5) and the LkIF display-unit enum give these six choices.
DISPLAY_UNITS: Final[Mapping[DisplayUnit, UnitFormat]] = {
    "0.01mm": UnitFormat("0.01mm", 2, 1.0),  # +-9999.99 mm
    "0.001mm": UnitFormat("0.001mm", 3, 1.0),  # +-999.999 mm
    "0.0001mm": UnitFormat("0.0001mm", 4, 1.0),  # +-99.9999 mm
    "0.00001mm": UnitFormat("0.00001mm", 5, 1.0),  # +-9.99999 mm
    "0.1um": UnitFormat("0.1um", 1, 0.001),  # +-99999.9 um
    "0.01um": UnitFormat("0.01um", 2, 0.001),  # +-9999.99 um
}


def unit_format(name: str) -> UnitFormat:
    """The format of a display-unit setting, or a ValueError naming the choices."""
    try:
        return DISPLAY_UNITS[name]  # type: ignore[index]
    except KeyError:
        raise ValueError(f"display unit {name!r} is not one of {', '.join(DISPLAY_UNITS)}") from None


class ValueKind(enum.Enum):
    """What an 8-character value token says."""

    NUMBER = "number"
    OVER_RANGE_PLUS = "over_range_plus"
    OVER_RANGE_MINUS = "over_range_minus"
    NO_VALUE = "no_value"


@dataclass(frozen=True)
class WireValue:
    """A decoded value token: its kind, and for a number the value in mm (display offset included)."""

    kind: ValueKind
    mm: float | None
    token: str


class ValueFormatError(ValueError):
    """A value token that is not a valid measurement value for the configured display unit."""


def parse_value(token: str, unit: UnitFormat) -> WireValue:
    """Decode one value token; anything that is not exactly a valid token raises ValueFormatError.

    A number must have exactly the configured unit's decimals: a controller set to another unit
    is reported, not read with the wrong scale.
    """
    if token == OVER_RANGE_PLUS:
        return WireValue(ValueKind.OVER_RANGE_PLUS, None, token)
    if token == OVER_RANGE_MINUS:
        return WireValue(ValueKind.OVER_RANGE_MINUS, None, token)
    if token == NO_VALUE:
        return WireValue(ValueKind.NO_VALUE, None, token)
    if _VALUE_RE.fullmatch(token) is None or token.count(".") != 1:
        raise ValueFormatError(f"{token!r} is not a measurement value (sign and 7 characters with one decimal point)")
    decimals = len(token) - token.index(".") - 1
    if decimals != unit.decimals:
        candidates = [u.name for u in DISPLAY_UNITS.values() if u.decimals == decimals]
        raise ValueFormatError(
            f"value {token!r} has {decimals} decimals but display unit {unit.name} sends {unit.decimals}: "
            f"the controller's minimum display unit differs from devices.laser.display_unit "
            f"(a value with {decimals} decimals fits {' or '.join(candidates) or 'no known unit'})"
        )
    return WireValue(ValueKind.NUMBER, float(token) * unit.mm_per_unit, token)


def format_value(mm: float, unit: UnitFormat) -> str:
    """Encode a value in mm as the controller shows it; one beyond the 7 characters is over range."""
    counts = round(mm / unit.resolution_mm)
    if abs(counts) > 999_999:
        return OVER_RANGE_PLUS if counts > 0 else OVER_RANGE_MINUS
    sign = "-" if counts < 0 else "+"
    digits = f"{abs(counts):06d}"  # six digits and the decimal point make the seven characters
    return f"{sign}{digits[: 6 - unit.decimals]}.{digits[6 - unit.decimals:]}"


def format_setting_integer(mm: float, unit: UnitFormat) -> str:
    """A value as the setting-change format wants it: sign and six digits, no decimal point (p. 5-6)."""
    counts = round(mm / unit.resolution_mm)
    if abs(counts) > 999_999:
        raise ValueError(f"{mm} mm does not fit the setting format at display unit {unit.name}")
    return f"{'-' if counts < 0 else '+'}{abs(counts):06d}"


def parse_setting_integer(token: str, unit: UnitFormat) -> float:
    """Decode the setting-change format (sign and six digits) to mm."""
    if re.fullmatch(r"[+-][0-9]{6}", token) is None:
        raise ValueFormatError(f"{token!r} is not a setting value (sign and six digits, no decimal point)")
    return int(token) * unit.resolution_mm
