"""The error codes of the two LK-G controller dialects and what each means.

An error reply is ``ER,<main command>,<two-digit code>`` on both controllers, but the numbers
differ: the LK-G3001 numbers its errors 00..22 (manual p. 5-5), the LK-G5001 50..62 (LK-G5000
manual, as transcribed in public LK-G5000 drivers). 88 and 99 are shared.
"""

from __future__ import annotations

from typing import Final, Literal, Mapping

Dialect = Literal["LK-G3001", "LK-G5001"]
DIALECTS: Final[tuple[Dialect, ...]] = ("LK-G3001", "LK-G5001")

ERROR_CODES: Final[Mapping[Dialect, Mapping[str, str]]] = {
    "LK-G3001": {
        "00": "command error (the controller does not know this command)",
        "01": "status error (not allowed in the current mode: settings need communication mode, "
        "measurement commands need general mode)",
        "20": "command length error",
        "21": "parameter count error",
        "22": "invalid parameter error",
        "88": "timeout error (the controller timed out internally)",
        "99": "other error",
    },
    "LK-G5001": {
        "50": "command error (the controller does not know this command)",
        "51": "status error (not allowed in the current mode: settings need communication mode, "
        "measurement commands need general mode)",
        "60": "command length error",
        "61": "parameter count error",
        "62": "parameter range error",
        "88": "timeout error (the controller timed out internally)",
        "99": "other error",
    },
}

# The code each dialect answers with for a command that is not allowed in the current mode.
STATUS_ERROR: Final[Mapping[Dialect, str]] = {"LK-G3001": "01", "LK-G5001": "51"}
COMMAND_ERROR: Final[Mapping[Dialect, str]] = {"LK-G3001": "00", "LK-G5001": "50"}
LENGTH_ERROR: Final[Mapping[Dialect, str]] = {"LK-G3001": "20", "LK-G5001": "60"}
PARAMETER_COUNT_ERROR: Final[Mapping[Dialect, str]] = {"LK-G3001": "21", "LK-G5001": "61"}
PARAMETER_ERROR: Final[Mapping[Dialect, str]] = {"LK-G3001": "22", "LK-G5001": "62"}
TIMEOUT_ERROR: Final = "88"
OTHER_ERROR: Final = "99"


def describe_error(dialect: Dialect, code: str) -> str:
    """What ``code`` means on ``dialect``; a code of the other dialect is named as a likely misconfiguration."""
    table = ERROR_CODES[dialect]
    if code in table:
        return f"{dialect} error {code}: {table[code]}"
    for other, other_table in ERROR_CODES.items():
        if other != dialect and code in other_table:
            return (
                f"error code {code} is not an {dialect} code but means '{other_table[code]}' on the {other}: "
                f"check that devices.laser.dialect names the controller actually connected"
            )
    return f"unknown {dialect} error code {code!r}"
