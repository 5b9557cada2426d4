"""SIGTERM (what systemd sends) stops `cellctl serve` as Ctrl-C does, even with a dashboard's event stream open."""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path

import httpx
import pytest
from service_test_support import free_port, sim_toml, start_serve, wait_up


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_the_service_cleanly_with_an_event_stream_open(tmp_path: Path, sig: signal.Signals) -> None:
    port = free_port()
    cfg = tmp_path / "cell.toml"
    cfg.write_text(sim_toml(port))
    proc = start_serve(cfg, tmp_path)
    url = f"http://127.0.0.1:{port}"
    streamed: list[str] = []
    try:
        wait_up(url, proc, tmp_path)

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
    assert code == (130 if sig == signal.SIGINT else 0), (tmp_path / "service.log").read_text()
    assert "event: shutdown" in streamed  # the stream was ended by the service, not cut
    assert not (tmp_path / "var" / "cellctl.db-wal").exists() or (tmp_path / "var" / "cellctl.db-wal").stat().st_size == 0
    assert "Traceback" not in (tmp_path / "service.log").read_text()
