"""The fake LK-G controller's storage commands (AQ/AS/AP/AN/AO) answer an error with the code keyence_lkg.md A6
gives: a wrong argument count is 21 (LK-G3001) / 61 (LK-G5001), a bad value 22 / 62.

Peer: raw bytes on the fake's pseudo-terminal (opened by path like a serial adapter), no driver code.
"""

from __future__ import annotations

import os
import select
import time
import tty

import pytest

from keyence_lkg.fake import FakeLkgController


def ask(path: str, lines: list[str]) -> list[str]:
    """Send each line with CR on the raw port and return each CR-terminated reply (ASCII, CR stripped)."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        tty.setraw(fd)
        replies = []
        for line in lines:
            os.write(fd, line.encode("ascii") + b"\r")
            buf = b""
            deadline = time.monotonic() + 2.0
            while not buf.endswith(b"\r"):
                left = deadline - time.monotonic()
                assert left > 0 and select.select([fd], [], [], left)[0], f"no reply to {line!r}: got {buf!r}"
                buf += os.read(fd, 1)
            replies.append(buf[:-1].decode("ascii"))
        return replies
    finally:
        os.close(fd)


# (dialect, command, reply): keyence_lkg.md A6 "Wrong argument count -> 21|61. Bad value -> 22|62"
CASES = [
    ("LK-G3001", "M1,1", "ER,M1,21"),  # the fake's measurement commands, for comparison
    ("LK-G3001", "AQ,1", "ER,AQ,21"),
    ("LK-G3001", "AS,1", "ER,AS,21"),
    ("LK-G3001", "AP,1", "ER,AP,21"),
    ("LK-G3001", "AN,1", "ER,AN,21"),
    ("LK-G3001", "AO", "ER,AO,21"),
    ("LK-G3001", "AO,1,2", "ER,AO,21"),
    ("LK-G3001", "AO,X", "ER,AO,22"),  # bad value
    ("LK-G3001", "AO,2", "ER,AO,22"),  # an OUT nothing was stored for
    ("LK-G5001", "MA,01", "ER,MA,61"),
    ("LK-G5001", "AQ,01", "ER,AQ,61"),
    ("LK-G5001", "AS,01", "ER,AS,61"),
    ("LK-G5001", "AP,01", "ER,AP,61"),
    ("LK-G5001", "AN,01", "ER,AN,61"),
    ("LK-G5001", "AO", "ER,AO,61"),
    ("LK-G5001", "AO,01,02", "ER,AO,61"),
    ("LK-G5001", "AO,+1", "ER,AO,62"),  # bad value
    ("LK-G5001", "AO,07", "ER,AO,62"),  # an OUT nothing was stored for
]


@pytest.mark.parametrize(("dialect", "command", "expected"), CASES)
def test_storage_command_error_codes(dialect: str, command: str, expected: str) -> None:
    with FakeLkgController(dialect, lambda: 350.0) as fake:  # type: ignore[arg-type]
        assert ask(fake.path, [command]) == [expected]


@pytest.mark.parametrize("dialect", ["LK-G3001", "LK-G5001"])
def test_storage_commands_with_right_count_still_answer(dialect: str) -> None:
    """The same commands with the right argument count echo (the fake's storage is empty: AN says 0 held)."""
    with FakeLkgController(dialect, lambda: 350.0) as fake:  # type: ignore[arg-type]
        assert ask(fake.path, ["AQ", "AP", "AN"]) == ["AQ", "AP", "AN,0,0"]
