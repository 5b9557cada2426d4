"""A relative `[[api.tokens]] token_file` is read from `--workdir`, as every other relative path of the configuration
(the store, the OPC UA certificates, the MQTT password file), not from the process's current folder; an error names
the absolute path it looked at."""

from __future__ import annotations

import os
import secrets
from pathlib import Path

import httpx
import pytest
from service_test_support import free_port, sim_toml, start_serve, wait_up
from shared_support import run_cli

pytestmark = pytest.mark.timeout(180)
SIM_TOKEN_LINE = 'token = "sim-operator-token-change-me"'


def _config(workdir: Path, port: int) -> Path:
    text = sim_toml(port)
    assert text.count(SIM_TOKEN_LINE) == 1
    cfg = workdir / "cell.toml"
    cfg.write_text(text.replace(SIM_TOKEN_LINE, 'token_file = "api-token"'))
    return cfg


def _token(workdir: Path) -> str:
    value = secrets.token_urlsafe(32)
    (workdir / "api-token").write_text(value + "\n")
    os.chmod(workdir / "api-token", 0o600)
    return value


def test_config_check_reads_a_relative_token_file_from_the_workdir(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _token(tmp_path)
    assert Path.cwd() != tmp_path and not (Path.cwd() / "api-token").exists()
    cfg = _config(tmp_path, 0)
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    assert rc == 0 and "every API token" in out, err


def test_a_missing_token_file_is_named_by_its_absolute_path(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = _config(tmp_path, 0)
    rc, _, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    assert rc == 2 and f"api.tokens 'operator': token_file: {tmp_path / 'api-token'} does not exist" in err, err


def test_serve_reads_a_relative_token_file_from_its_workdir(tmp_path: Path) -> None:
    token = _token(tmp_path)
    port = free_port()
    proc = start_serve(_config(tmp_path, port), tmp_path)  # its current folder is the test's, not the workdir
    url = f"http://127.0.0.1:{port}"
    try:
        wait_up(url, proc, tmp_path)
        ok = httpx.post(f"{url}/alarms/acknowledge-all", headers={"Authorization": f"Bearer {token}"}, timeout=5.0)
        wrong = httpx.post(f"{url}/alarms/acknowledge-all", headers={"Authorization": "Bearer sim-operator-token-change-me"},
                           timeout=5.0)  # fmt: skip
    finally:
        proc.terminate()
        code = proc.wait(timeout=30)
    assert ok.status_code == 200 and wrong.status_code == 401, (ok.text, wrong.text)
    assert code == 0, (tmp_path / "service.log").read_text()
