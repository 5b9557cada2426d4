"""SIGTERM (what systemd sends) stops `cellctl serve` as Ctrl-C does, even with a dashboard's event stream open."""

from __future__ import annotations

import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest
from service_test_support import ROOT


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_the_service_cleanly_with_an_event_stream_open(tmp_path: Path, sig: signal.Signals) -> None:
    port = _free_port()
    text = (ROOT / "config" / "sim.toml").read_text()
    text = re.sub(r'(?m)^source = "set"$', 'source = "oracle"', text, count=1)
    text = re.sub(r"(?m)^port = 8080$", f"port = {port}", text, count=1)
    text = text.replace("[plc]                                  # Modbus TCP server for the line PLC\nenabled = true", "[plc]\nenabled = false")
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text)
    log = open(tmp_path / "service.log", "ab")  # noqa: SIM115
    proc = subprocess.Popen([sys.executable, "-m", "cellctl.cli", "--config", str(cfg), "serve", "--workdir", str(tmp_path)],
                            stdout=log, stderr=log)  # fmt: skip
    url = f"http://127.0.0.1:{port}"
    streamed: list[str] = []
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"{url}/status", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert proc.poll() is None and time.monotonic() < deadline, (tmp_path / "service.log").read_text()
            time.sleep(0.2)

        def listen() -> None:  # a dashboard that never lets go of its stream
            try:
                with httpx.stream("GET", f"{url}/events", timeout=httpx.Timeout(5.0, read=120.0)) as r:
                    for line in r.iter_lines():
                        streamed.append(line)
            except httpx.HTTPError:
                streamed.append("<error>")

        threading.Thread(target=listen, daemon=True).start()
        while not any(line.startswith("event: status") for line in streamed):
            time.sleep(0.05)
        proc.send_signal(sig)
        code = proc.wait(timeout=30)  # a stream held open kept it alive 43 s before
    finally:
        if proc.poll() is None:
            proc.kill()
        log.close()
    assert code == (130 if sig == signal.SIGINT else 0), (tmp_path / "service.log").read_text()
    assert "event: shutdown" in streamed  # the stream was ended by the service, not cut
    assert not (tmp_path / "var" / "cellctl.db-wal").exists() or (tmp_path / "var" / "cellctl.db-wal").stat().st_size == 0
    assert "Traceback" not in (tmp_path / "service.log").read_text()
