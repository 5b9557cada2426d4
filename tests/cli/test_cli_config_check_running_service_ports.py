"""`config check --secrets` beside the running service of the same configuration says what it checked: the listen ports
are the service's own and were not checked, so its summary must not say every listen port is free (the OS shows them
listening); once the service has stopped it checks them and says they are free (the OS shows nothing listening)."""

from __future__ import annotations

import signal
import socket
from pathlib import Path

import pytest
from service_test_support import sim_toml, start_serve, wait_up
from shared_support import LOOPBACK, free_port, run_cli

pytestmark = pytest.mark.timeout(240)
NOT_CHECKED = "the listen ports were not checked (the service of this configuration runs and holds them)"


def _listening(port: int) -> bool:
    """Whether the OS has a listener on the loopback ``port`` (a TCP connect is accepted)."""
    with socket.socket() as sock:
        sock.settimeout(2)
        return sock.connect_ex((LOOPBACK, port)) == 0


def test_the_summary_says_the_ports_were_not_checked_while_the_service_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    port = free_port()
    cfg = tmp_path / "cell.toml"
    cfg.write_text(sim_toml(port), encoding="utf-8")
    check = ("config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    proc = start_serve(cfg, tmp_path)
    try:
        wait_up(f"http://{LOOPBACK}:{port}", proc, tmp_path)
        rc, out, err = run_cli(capsys, *check)
        assert _listening(port)  # the OS: the service's port is in use while the check ran
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
    assert rc == 0, err
    assert f"note: the service of this configuration is running (pid {proc.pid}): its listen ports were not checked" in out
    assert "every listen port is free" not in out, out
    secrets = next(line for line in out.splitlines() if line.strip().startswith("secrets"))
    assert secrets.endswith(NOT_CHECKED), secrets

    assert not _listening(port)  # the OS: nothing listens once the service has stopped
    rc, out, err = run_cli(capsys, *check)
    assert rc == 0 and "note: the service" not in out, out + err
    secrets = next(line for line in out.splitlines() if line.strip().startswith("secrets"))
    assert secrets.endswith("and every listen port is free now"), secrets
