"""kill -9 during the install, restart: the cycle is recorded as interrupted and never repeated."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
from service_test_support import AUTH, ROOT


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _write_config(path: Path, port: int) -> None:
    text = (ROOT / "config" / "sim.toml").read_text()
    # Slow the simulated motion so the install step lasts long enough to be killed in.
    text = re.sub(r"(?m)^time_scale = .*$", "time_scale = 0.3", text, count=1)
    text = re.sub(r'(?m)^source = "set"$', 'source = "oracle"', text, count=1)  # no half-minute self-calibration
    text = re.sub(r"(?m)^port = 8080$", f"port = {port}", text, count=1)
    text = text.replace("[plc]                                  # Modbus TCP server for the line PLC\nenabled = true",
                        "[plc]\nenabled = false")  # fmt: skip
    path.write_text(text)


def _start(config: Path, workdir: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "cellctl.cli", "--config", str(config), "serve", "--workdir", str(workdir)],
        stdout=subprocess.DEVNULL, stderr=open(workdir / "service.log", "ab"),  # noqa: SIM115
    )  # fmt: skip


def _wait_up(client: httpx.Client, deadline_s: float = 60.0) -> None:
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        try:
            if client.get("/status").status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.1)
    raise AssertionError("the service did not come up")


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
    port = _free_port()
    config = tmp_path / "cell.toml"
    _write_config(config, port)
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10.0)
    proc = _start(config, tmp_path)
    try:
        _wait_up(client)
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
    proc = _start(config, tmp_path)
    try:
        _wait_up(client)
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
