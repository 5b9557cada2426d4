"""kill -9 during the install, restart: the cycle is recorded as interrupted and never repeated."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import httpx
from service_test_support import AUTH, free_port, sim_toml, start_serve, wait_up


def _settle(client: httpx.Client) -> str:
    for _ in range(300):
        state = client.get("/status").json()["state"]
        if not state.endswith("ING"):
            return state
        time.sleep(0.02)
    raise AssertionError("the cell stayed in an acting state")


def _to_execute(client: httpx.Client) -> None:
    for cmd in ("clear", "reset", "start"):
        assert client.post(f"/commands/{cmd}", headers=AUTH).status_code == 200
        _settle(client)
    assert client.get("/status").json()["state"] == "EXECUTE"


def test_kill_9_during_install_then_restart_repeats_nothing(tmp_path: Path) -> None:
    port = free_port()
    config = tmp_path / "cell.toml"
    config.write_text(sim_toml(port, time_scale=0.3))  # slow moves: the install step lasts long enough to be killed in
    url = f"http://127.0.0.1:{port}"
    client = httpx.Client(base_url=url, timeout=10.0)
    proc = start_serve(config, tmp_path)
    try:
        wait_up(url, proc, tmp_path)
        _to_execute(client)
        body = {"recipe": "side-window", "part_id": "P-77"}
        r = client.post("/cycle", json=body, headers={**AUTH, "Idempotency-Key": "crash-1"})
        assert r.status_code == 202, r.text
        cycle_id = r.json()["cycle_id"]
        end = time.monotonic() + 120
        while client.get("/status").json()["cycle_step"] != "install":
            assert time.monotonic() < end, "the cycle never reached install"
            time.sleep(0.01)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    proc = start_serve(config, tmp_path)
    try:
        wait_up(url, proc, tmp_path)
        status = client.get("/status").json()
        assert status["state"] in ("ABORTED", "STOPPED")
        rec = client.get(f"/cycles/{cycle_id}").json()
        assert rec["state"] == "interrupted", rec
        assert rec["interrupted_step"] == "install" and rec["install_started_at"] is not None
        alarms = client.get("/alarms").json()["current"]
        assert any(a["code"] == 1306 and a["cycle_id"] == cycle_id for a in alarms), alarms
        # Back in production, nothing resumes the interrupted cycle, and its key gives it back unchanged.
        for a in alarms:
            client.post(f"/alarms/{a['uid']}/acknowledge", headers=AUTH)
        _to_execute(client)
        again = client.post("/cycle", json=body, headers={**AUTH, "Idempotency-Key": "crash-1"})
        assert again.status_code == 202 and again.json()["cycle_id"] == cycle_id and again.json()["created"] is False
        time.sleep(1.0)
        assert client.get(f"/cycles/{cycle_id}").json()["state"] == "interrupted"
        assert [c["id"] for c in client.get("/cycles").json()] == [cycle_id]
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
