"""Issue 20, deploy: the systemd unit verifies and may bind the PLC's port 502, the container file has a
HEALTHCHECK on /health/live (liveness) and a base pinned by digest, and the project is licensed."""

from __future__ import annotations

import http.server
import json
import re
import shutil
import subprocess
import sys
import threading
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest
from shared_support import skip_or_fail

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "deploy" / "cellctl.service"
CONTAINERFILE = REPO / "deploy" / "Containerfile"
INSTALLED_EXEC = "/opt/cellctl/.venv/bin/cellctl"


def _unit_settings(text: str) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in text.splitlines():
        if "=" in line and not line.lstrip().startswith(("#", ";", "[")):
            key, _, value = line.partition("=")
            out.setdefault(key.strip(), []).append(value.strip())
    return out


def test_systemd_analyze_verifies_the_unit(tmp_path: Path) -> None:
    """The unit as shipped, with ExecStart pointing at this checkout's cellctl (verify needs the binary to exist)."""
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        skip_or_fail("systemd-analyze is not installed", "scripts/system-packages installs Debian's systemd for it")
    cellctl = Path(sys.executable).with_name("cellctl")
    assert cellctl.exists(), f"{cellctl}: install the package into the venv (scripts/setup)"
    text = UNIT.read_text()
    assert f"ExecStart={INSTALLED_EXEC} " in text
    unit = tmp_path / "cellctl.service"
    unit.write_text(text.replace(INSTALLED_EXEC, str(cellctl)))
    r = subprocess.run([analyze, "verify", str(unit)], capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 0 and not r.stderr.strip(), f"rc {r.returncode}: {r.stdout}{r.stderr}"


def test_the_unit_may_bind_the_plc_port_and_keeps_its_hardening() -> None:
    s = _unit_settings(UNIT.read_text())
    hardware = tomllib.loads((REPO / "config" / "hardware.example.toml").read_text())
    assert hardware["plc"]["port"] < 1024  # the reason for CAP_NET_BIND_SERVICE
    assert s["User"] == ["cellctl"]
    ambient = set(" ".join(s["AmbientCapabilities"]).split())
    bounding = set(" ".join(s["CapabilityBoundingSet"]).split())
    assert ambient == {"CAP_NET_BIND_SERVICE", "CAP_SYS_NICE"} and ambient <= bounding == ambient
    for key, value in {"NoNewPrivileges": "yes", "ProtectSystem": "strict", "ProtectHome": "yes", "PrivateTmp": "yes",
                       "ReadWritePaths": "/var/lib/cellctl", "KillSignal": "SIGTERM"}.items():  # fmt: skip
        assert s[key] == [value], key


def _containerfile() -> list[str]:
    """The instructions, continuation lines joined, comments dropped."""
    joined = re.sub(r"\\\n\s*", " ", CONTAINERFILE.read_text())
    return [line.strip() for line in joined.splitlines() if line.strip() and not line.lstrip().startswith("#")]


def test_the_container_base_is_pinned_by_digest() -> None:
    lines = _containerfile()
    arg = next(line for line in lines if line.startswith("ARG PYTHON_IMAGE="))
    assert re.fullmatch(r"ARG PYTHON_IMAGE=python:3\.11-slim-bookworm@sha256:[0-9a-f]{64}", arg), arg
    assert lines.index(arg) < lines.index("FROM ${PYTHON_IMAGE}")
    assert any(line.startswith("COPY ") and "LICENSE" in line for line in lines)  # pyproject's license-files


class _Health(http.server.BaseHTTPRequestHandler):
    """A served cell as README's "Health and metrics" gives it: /health/live (liveness) and /health (readiness)."""

    live = 200
    ready = 200

    def do_GET(self) -> None:
        self.send_response({"/health/live": self.live, "/health": self.ready}.get(self.path, 404))
        self.end_headers()
        self.wfile.write(b'{"ok": true}')

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def health_server() -> Iterator[http.server.HTTPServer]:
    server = http.server.HTTPServer(("127.0.0.1", 0), _Health)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield server
    server.shutdown()
    server.server_close()


def test_the_healthcheck_is_liveness_a_cell_waiting_for_its_plc_is_healthy(health_server: http.server.HTTPServer) -> None:
    """An orchestrator restarts an unhealthy container (podman --health-on-failure=restart, Swarm): the check must
    fail only when the process does not serve (README: restart only when /health/live fails), not while a device
    or the PLC is down (/health answers 503 then)."""
    lines = _containerfile()
    check = next(line for line in lines if line.startswith("HEALTHCHECK "))
    options, _, command = check.partition(" CMD ")
    assert re.search(r"--interval=\d+s", options) and re.search(r"--start-period=\d+s", options), options
    argv = json.loads(command)
    assert argv[:2] == ["python", "-c"]
    env_line = next(line for line in lines if line.startswith("ENV CELLCTL_HEALTH_URL="))
    url = env_line.split("=", 1)[1].replace("127.0.0.1:8080", f"127.0.0.1:{health_server.server_address[1]}")
    for live, ready, ok in ((200, 200, True), (200, 503, True), (503, 503, False)):
        _Health.live, _Health.ready = live, ready
        r = subprocess.run([sys.executable, "-c", argv[2]], env={"CELLCTL_HEALTH_URL": url}, capture_output=True, timeout=30,
                           check=False)
        assert (r.returncode == 0) is ok, (live, ready, r.stderr)


def test_the_project_is_apache_2_licensed() -> None:
    text = (REPO / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text and "END OF TERMS AND CONDITIONS" in text
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert project["license"] == "Apache-2.0" and project["license-files"] == ["LICENSE"]
