"""SIGTERM (what systemd sends) stops `cellctl serve` as Ctrl-C does, even with a dashboard's event stream open."""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path

import httpx
import pytest
from service_test_support import AUTH, free_port, sim_toml, start_serve, wait_up


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


def test_a_signal_mid_cycle_stops_the_cycle_and_records_it_before_the_exit(tmp_path: Path) -> None:
    """systemd's stop during the alignment: the robot stops, no later step (above all no install) begins, the cycle is
    recorded as stopped, and the caller waiting on it gets its answer; read with sqlite3 right after the exit."""
    import sqlite3

    port = free_port()
    cfg = tmp_path / "cell.toml"
    cfg.write_text(sim_toml(port, time_scale=0.05))  # a cycle of a couple of seconds
    proc = start_serve(cfg, tmp_path)
    url = f"http://127.0.0.1:{port}"
    answer: list[httpx.Response] = []
    try:
        wait_up(url, proc, tmp_path)
        with httpx.Client() as http:  # one client for the polls: a new one per request loads the CA bundle (~20 ms of CPU)
            for cmd in ("clear", "reset", "start"):
                assert http.post(f"{url}/commands/{cmd}", headers=AUTH, timeout=30).status_code == 200
                while http.get(f"{url}/status").json()["state"].endswith("ING"):
                    time.sleep(0.02)

            def wait_for_it() -> None:
                answer.append(httpx.post(f"{url}/cycle?wait=true&timeout_s=60", json={"recipe": "side-window", "part_id": "G/1"},
                                         headers={**AUTH, "Idempotency-Key": "sigterm-1"}, timeout=70))

            waiter = threading.Thread(target=wait_for_it)
            waiter.start()
            while http.get(f"{url}/status").json()["cycle_step"] != "align":
                time.sleep(0.01)
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=30)
        waiter.join(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert code == 0, (tmp_path / "service.log").read_text()[-3000:]
    with sqlite3.connect(tmp_path / "var" / "cellctl.db") as c:
        state, error, installed = c.execute("SELECT state, error, install_started_at FROM cycles").fetchone()
        steps = [s for (s,) in c.execute("SELECT step FROM cycle_steps ORDER BY id")]
    assert (state, installed) == ("failed", None) and error.startswith("stopped: the service is stopping"), (state, error)
    assert max(steps) <= 2, steps  # calibrate (1) and align (2): nothing began after the signal
    assert answer and answer[0].status_code == 200 and answer[0].json()["state"] == "failed", answer
