"""The fake ABB controller's EGM datagrams carry ``EgmClock`` (feedBack.time, planned.time) as egm.proto defines it:
seconds and microseconds since 1 Jan 1970; ``header.tm`` stays on the controller's uptime clock (ms).

Peers: a raw TCP socket speaking the line protocol, a UDP socket taking the datagrams, and ABB's reference
egm.proto (/work/shared/reference) compiled with protoc and decoding the bytes in a process of its own. Truth: the
host's wall clock (``time.time``) around the exchange.
"""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from _abb_testkit import LOOPBACK, start_fake

REFERENCE_PROTO = Path(__file__).resolve().parents[3] / "shared" / "reference" / "egm.proto"
# Without ABB's file beside the repository (a clean checkout): the driver's copy of the schema, whose field numbers
# tests/drivers/test_abb_egm_proto.py checks against ABB's where that file is; still compiled apart from the fake.
OWN_PROTO = Path(__file__).resolve().parents[2] / "drivers" / "abb_robot" / "egm" / "egm.proto"
UPTIME_MS = 123_456
DECODE = """
import json, sys
sys.path.insert(0, sys.argv[1])
import egm_pb2 as pb
out = []
for line in sys.stdin:
    m = pb.EgmRobot.FromString(bytes.fromhex(line.strip()))
    out.append([m.header.seqno, m.header.tm, m.feedBack.time.sec, m.feedBack.time.usec,
                m.planned.time.sec, m.planned.time.usec])
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def reference_decoder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with ABB's egm.proto (else the driver's copy) compiled to egm_pb2.py."""
    pytest.importorskip("grpc_tools", reason="grpcio-tools (dev extra) compiles ABB's schema")
    folder = tmp_path_factory.mktemp("abb_egm")
    shutil.copy(REFERENCE_PROTO if REFERENCE_PROTO.exists() else OWN_PROTO, folder / "egm.proto")
    subprocess.run([sys.executable, "-m", "grpc_tools.protoc", "-I", str(folder), f"--python_out={folder}", "egm.proto"],
                   check=True, timeout=60)
    return folder


def decode(folder: Path, datagrams: list[bytes]) -> list[list[int]]:
    """(seqno, tm, feedBack sec, usec, planned sec, usec) of each datagram, by the reference schema."""
    run = subprocess.run([sys.executable, "-c", DECODE, str(folder)], input="\n".join(d.hex() for d in datagrams),
                         capture_output=True, text=True, check=True, timeout=60)
    return json.loads(run.stdout)


class Line:
    """The line protocol over a plain TCP socket."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection((LOOPBACK, port), timeout=3.0)
        self.file = self.sock.makefile("rwb")

    def ask(self, line: str) -> str:
        self.file.write(line.encode("ascii") + b"\n")
        self.file.flush()
        return self.read()

    def read(self) -> str:
        return self.file.readline().decode("ascii").strip()

    def close(self) -> None:
        self.file.close()
        self.sock.close()


def collect(sensor: socket.socket, n: int) -> list[tuple[bytes, float]]:
    """``n`` datagrams, each with the wall clock when it was read (UNIX s)."""
    return [(sensor.recvfrom(4096)[0], time.time()) for _ in range(n)]


def check_epoch(rows: list[list[int]], walls: list[float], before: float) -> None:
    for (seq, tm, sec, usec, psec, pusec), wall in zip(rows, walls):
        assert 0 <= usec < 1_000_000 and (psec, pusec) == (sec, usec), (seq, sec, usec, psec, pusec)
        stamp = sec + usec * 1e-6
        # sampled after the request went out, before the datagram was read (the stamp names the ms nearest the read)
        assert before - 0.001 <= stamp <= wall + 0.001, (
            f"seqno {seq}: EgmClock {stamp:.6f} s is not the wall clock (between {before:.6f} and {wall:.6f} s)")
        assert UPTIME_MS <= tm < UPTIME_MS + 60_000, f"seqno {seq}: header.tm {tm} is not on the uptime clock"


def exchange(
    start: tuple[str, str], count: int, stop: tuple[str, str], ended: str | None = None
) -> tuple[list[tuple[bytes, float]], float]:
    """On a fresh fake: HELLO, ``start`` (request, answer), ``count`` datagrams, ``stop`` with the started request's own
    end line (``ended``: how it begins; it comes once the stopped session has ended, before or after the stop's answer,
    and before BYE's unless read), BYE; the datagrams with their read times and the wall clock before ``start``."""
    sensor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sensor.bind((LOOPBACK, 0))
    sensor.settimeout(2.0)
    fake = start_fake(egm_sensor_port=sensor.getsockname()[1], time_scale=0.2, egm_uptime_ms=UPTIME_MS)
    assert fake.rapid_port is not None
    line = Line(fake.rapid_port)
    try:
        assert line.ask("1 HELLO 1").startswith("1 OK 1 ")
        before = time.time()
        assert line.ask(start[0]) == start[1]
        got = collect(sensor, count)
        answers = [line.ask(stop[0])] + ([] if ended is None else [line.read()])  # the two in either order
        assert stop[1] in answers and (ended is None or any(a.startswith(ended) for a in answers)), answers
        assert line.ask("4 BYE") == "4 OK"
    finally:
        line.close()
        fake.stop_thread()
        sensor.close()
    return got, before


def test_stream_datagrams_carry_unix_time(reference_decoder: Path) -> None:
    got, before = exchange(("2 STREAM 1", "2 OK 1"), 25, ("3 STREAM 0", "3 OK 0"))
    rows = decode(reference_decoder, [d for d, _ in got])
    assert [r[0] for r in rows] == list(range(25))
    check_epoch(rows, [w for _, w in got], before)
    # one instant: EgmClock names the instant tm names, so both advance alike (to the wall clock's reading of it)
    tm0, t0 = rows[0][1], rows[0][2] + rows[0][3] * 1e-6
    for seq, tm, sec, usec, _, _ in rows[1:]:
        assert abs((sec + usec * 1e-6 - t0) - (tm - tm0) / 1000.0) < 0.001, (seq, tm, sec, usec)


def test_guidance_session_datagrams_carry_unix_time(reference_decoder: Path) -> None:
    got, before = exchange(("2 EGM 0.1 0.1 1", "2 ACK"), 10, ("3 STOP", "3 OK 1"),  # STOP: the session was running
                           ended="2 ERR 140 ")  # fmt: skip
    rows = decode(reference_decoder, [d for d, _ in got])
    assert [r[0] for r in rows] == list(range(10))
    check_epoch(rows, [w for _, w in got], before)
