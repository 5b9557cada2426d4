"""A configuration problem `serve` finds while starting OPC UA or MQTT (a secret, certificate or key file it cannot use)
ends it with exit 2, "usage or configuration problem", on which deploy/cellctl.service does not restart
(RestartPreventExitStatus=2): starting again cannot help. A port another program holds stays exit 1 (it can clear)."""

from __future__ import annotations

import os
import re
import secrets
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from service_test_support import ROOT, sim_toml
from shared_support import LOOPBACK, free_port

pytestmark = pytest.mark.timeout(240)
UNIT = (ROOT / "deploy" / "cellctl.service").read_text()


def _serve(workdir: Path, text: str) -> subprocess.CompletedProcess[str]:
    cfg = workdir / "cell.toml"
    cfg.write_text(text)
    return subprocess.run([sys.executable, "-m", "cellctl.cli", "--config", str(cfg), "serve", "--workdir", str(workdir)],
                          capture_output=True, text=True, timeout=180, cwd=ROOT)  # fmt: skip


def _with_opcua(port: int, users: str = "") -> str:
    """The simulated cell (REST on a free port, PLC off) with its OPC UA server on ``port`` and ``users`` appended."""
    text = sim_toml(free_port()).replace("[opcua]\nenabled = false", "[opcua]\nenabled = true", 1)
    text, n = re.subn(r"(?m)^port = 4840 .*$", f"port = {port}", text, count=1)
    assert n == 1 and "[opcua]\nenabled = true" in text
    return text + users


def test_the_unit_does_not_restart_on_2() -> None:
    assert re.search(r"(?m)^RestartPreventExitStatus=2$", UNIT), UNIT


def test_an_mqtt_password_file_every_user_may_read_exits_2(tmp_path: Path) -> None:
    pw = tmp_path / "mqtt-password"
    pw.write_text(secrets.token_urlsafe(32) + "\n")
    os.chmod(pw, 0o644)
    mqtt = f'\n[mqtt]\nenabled = true\nhost = "{LOOPBACK}"\nport = {free_port()}\nusername = "cell"\npassword_file = "mqtt-password"\n'
    done = _serve(tmp_path, sim_toml(free_port()) + mqtt)
    last = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert last.startswith(f"error: MQTT publication cannot start: mqtt: password_file: {pw} can be read or written by every user")


def test_a_missing_opcua_user_certificate_exits_2(tmp_path: Path) -> None:
    users = '\n[[opcua.users]]\nname = "scada"\nrole = "viewer"\ncertificate = "/nonexistent/scada.der"\n'
    done = _serve(tmp_path, _with_opcua(free_port(), users))
    last = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert last.startswith("error: the OPC UA server cannot start: opcua.users 'scada': certificate /nonexistent/scada.der"), last


def test_an_opcua_port_another_program_holds_stays_exit_1(tmp_path: Path) -> None:
    with socket.socket() as held:
        held.bind((LOOPBACK, 0))
        held.listen()
        port = held.getsockname()[1]
        done = _serve(tmp_path, _with_opcua(port))
    last = done.stderr.strip().splitlines()[-1]  # (asyncua logs the bind's trace itself before)
    assert done.returncode == 1, done.stderr
    assert last.startswith(f"error: the OPC UA server cannot start: the OPC UA server cannot listen on {LOOPBACK}:{port}"), last
