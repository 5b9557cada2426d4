"""The fake controller's record of the lines it read stays bounded: a served simulated cell sends ~150 a cycle
for months, so the record keeps the newest ``RapidLineServer.KEEP_LINES`` and lets the oldest go.

Spoken to over a plain loopback TCP socket (the OS's, not the driver), with more PINGs than the record keeps.
"""

from __future__ import annotations

import socket

import pytest

from _abb_testkit import LOOPBACK, start_fake
from abb_robot.fake.rapid_server import RapidLineServer

pytestmark = pytest.mark.timeout(60)


def _talk(port: int, lines: list[str]) -> list[str]:
    """Send the lines in batches, read one reply line per line sent; the replies."""
    replies: list[str] = []
    with socket.create_connection((LOOPBACK, port), timeout=10.0) as s, s.makefile("rb") as f:
        for i in range(0, len(lines), 200):
            batch = lines[i : i + 200]
            s.sendall("".join(f"{line}\n" for line in batch).encode("ascii"))
            replies += [f.readline().decode("ascii").rstrip("\n") for _ in batch]
    return replies


def test_the_fake_keeps_the_newest_lines_only() -> None:
    keep = RapidLineServer.KEEP_LINES
    assert 100 <= keep <= 50_000  # enough for the tests that read it, a bound all the same
    fake = start_fake(time_scale=0.05)
    try:
        assert fake.server is not None and fake.rapid_port is not None
        sent = ["1 HELLO 1"] + [f"{n} PING" for n in range(2, keep + 502)]
        replies = _talk(fake.rapid_port, sent)
        assert replies[-1] == f"{keep + 501} PONG", replies[-1]  # every line was read and answered
        got = fake.server.lines_received
        assert len(got) == keep, f"the fake kept {len(got)} lines of {len(sent)} (bound {keep})"
        assert got == sent[-keep:]  # the newest, oldest first
    finally:
        fake.stop_thread()


def test_a_smaller_record_keeps_its_bound() -> None:
    fake = start_fake(time_scale=0.05)
    try:
        assert fake.server is not None and fake.rapid_port is not None
        fake.server.keep_lines = 5
        sent = ["1 HELLO 1"] + [f"{n} PING" for n in range(2, 30)]
        _talk(fake.rapid_port, sent)
        assert fake.server.lines_received == sent[-5:]
    finally:
        fake.stop_thread()
