"""Connections that never send a request cannot take the service's file descriptors (review r4, D2).

A real `cellctl serve` on loopback, its open files limit lowered to 512 so the test stays cheap, and
600 silent TCP connections from 127.0.0.1: /health/live still answers another host (127.0.0.2), and
the server closes every silent connection itself within its request deadline.
"""

from __future__ import annotations

import resource
import socket
import subprocess
import sys
import time
from pathlib import Path

from service_test_support import free_port, sim_toml, wait_up
from shared_support import held_open

OPEN_FILES = 512  # asyncio accepts up to 100 connections at once before any is judged: room for such a burst
SILENT = 600
CLOSED_WITHIN_S = 30.0  # the deadline is 5 s; the margin is for a loaded machine


def _low_open_files() -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (OPEN_FILES, OPEN_FILES))


def _serve(cfg: Path, workdir: Path) -> subprocess.Popen[bytes]:
    with open(workdir / "service.log", "ab") as log:
        return subprocess.Popen([sys.executable, "-m", "cellctl.cli", "--config", str(cfg), "serve", "--workdir", str(workdir)],
                                stdout=log, stderr=log, preexec_fn=_low_open_files)  # fmt: skip


def _live(port: int, source: str) -> str:
    """The status line of GET /health/live sent from ``source``, or what went wrong."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=5, source_address=(source, 0)) as s:
            s.sendall(b"GET /health/live HTTP/1.1\r\nHost: cell\r\nConnection: close\r\n\r\n")
            return s.recv(200).split(b"\r\n")[0].decode() or "closed without an answer"
    except OSError as err:
        return f"failed: {err!r}"


def test_silent_connections_neither_starve_the_api_nor_stay_open(tmp_path: Path) -> None:
    port = free_port()
    cfg = tmp_path / "cell.toml"
    cfg.write_text(sim_toml(port))
    proc = _serve(cfg, tmp_path)
    held: list[socket.socket] = []
    try:
        wait_up(f"http://127.0.0.1:{port}", proc, tmp_path)
        for _ in range(SILENT):
            held.append(socket.create_connection(("127.0.0.1", port), timeout=5))
        time.sleep(0.5)  # the server has accepted what it will
        assert _live(port, "127.0.0.2").startswith("HTTP/1.1 200"), (tmp_path / "service.log").read_text()[-2000:]
        end = time.monotonic() + CLOSED_WITHIN_S
        while any(held_open(s) for s in held) and time.monotonic() < end:
            time.sleep(0.2)
        still = sum(held_open(s) for s in held)
        assert still == 0, f"{still} of {SILENT} silent connections still open after {CLOSED_WITHIN_S:g} s"
        assert _live(port, "127.0.0.1").startswith("HTTP/1.1 200")  # the crowding host is served again
        assert proc.poll() is None
    finally:
        for s in held:
            s.close()
        proc.terminate()
        proc.wait(30)
    assert "Too many open files" not in (tmp_path / "service.log").read_text()
