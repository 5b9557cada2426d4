"""`cellctl serve` with `[api] tls_cert` / `tls_key` answers over HTTPS (httpx trusting the self-signed certificate
the test made) and not over plain HTTP; a key every user may read refuses the start with exit 2; a hardware cell
listening beyond loopback without TLS logs the warning at start."""

from __future__ import annotations

import logging
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from service_test_support import ROOT, TOKEN, free_port, sim_config, sim_toml, start_serve
from tls_test_support import self_signed, trusting

from cellctl.service import build_service
from cellctl.service.compose import ServiceError

pytestmark = pytest.mark.timeout(180)
TLS_LINES = 'tls_cert = "tls/api-cert.pem"\ntls_key = "tls/api-key.pem"\n'  # relative: from serve --workdir


def _tls_config(workdir: Path, port: int) -> Path:
    (workdir / "tls").mkdir()
    self_signed(workdir / "tls")
    text = sim_toml(port).replace("\ncycle_wait_max_s = 600.0\n", "\ncycle_wait_max_s = 600.0\n" + TLS_LINES, 1)
    assert TLS_LINES in text
    cfg = workdir / "cell.toml"
    cfg.write_text(text)
    return cfg


def test_the_api_answers_over_https_and_not_over_plain_http(tmp_path: Path) -> None:
    port = free_port()
    cfg = _tls_config(tmp_path, port)
    cert = tmp_path / "tls" / "api-cert.pem"
    proc = start_serve(cfg, tmp_path)  # run from the test's folder, not the workdir: the relative files from --workdir
    try:
        with httpx.Client(verify=trusting(cert), timeout=5.0) as https:
            end = time.monotonic() + 60.0
            while True:
                try:
                    health = https.get(f"https://127.0.0.1:{port}/health")
                    break
                except httpx.ConnectError:
                    assert proc.poll() is None and time.monotonic() < end, (tmp_path / "service.log").read_text()
                    time.sleep(0.1)
            assert health.status_code == 200 and health.json()["ok"] is True, health.text
            assert health.extensions["http_version"] == b"HTTP/1.1"
            # a bearer token goes through the encrypted channel and is honoured
            ack = https.post(f"https://127.0.0.1:{port}/alarms/acknowledge-all", headers={"Authorization": f"Bearer {TOKEN}"})
            assert ack.status_code == 200, ack.text
        # the CLI trusts the plant's CA named by SSL_CERT_FILE (README), and only then
        cli = [sys.executable, "-m", "cellctl", "status", "--url", f"https://127.0.0.1:{port}"]
        env = {k: v for k, v in os.environ.items() if k not in ("SSL_CERT_FILE", "SSL_CERT_DIR")}
        trusted = subprocess.run(cli, env={**env, "SSL_CERT_FILE": str(cert)}, capture_output=True, text=True, timeout=60)
        assert trusted.returncode == 0 and trusted.stdout.startswith("state "), trusted.stderr
        untrusted = subprocess.run(cli, env=env, capture_output=True, text=True, timeout=60)
        assert untrusted.returncode == 1 and "CERTIFICATE_VERIFY_FAILED" in untrusted.stderr, untrusted.stderr
        with pytest.raises(httpx.ConnectError, match="CERTIFICATE_VERIFY_FAILED"):  # the peer checks, not trusting all
            httpx.get(f"https://127.0.0.1:{port}/health", timeout=5.0)
        with pytest.raises(httpx.TransportError):  # plain HTTP gets no HTTP answer from the TLS port
            httpx.get(f"http://127.0.0.1:{port}/health", timeout=5.0)
        with socket.create_connection(("127.0.0.1", port), timeout=5.0) as raw:  # the OS's view: no HTTP bytes back
            raw.sendall(b"GET /health HTTP/1.1\r\nHost: cell\r\n\r\n")
            try:
                answer = raw.recv(4096)
            except ConnectionResetError:
                answer = b""
            assert not answer.startswith(b"HTTP/"), f"the TLS port answered plain HTTP: {answer!r}"
    finally:
        proc.terminate()
        code = proc.wait(timeout=30)
    log = (tmp_path / "service.log").read_text()
    assert code == 0 and f"cellctl serving on https://127.0.0.1:{port}/" in log, log


def test_a_world_readable_tls_key_refuses_serve_with_exit_2(tmp_path: Path) -> None:
    cfg = _tls_config(tmp_path, free_port())
    key = tmp_path / "tls" / "api-key.pem"
    os.chmod(key, 0o644)
    done = subprocess.run([sys.executable, "-m", "cellctl.cli", "--config", str(cfg), "serve", "--workdir", str(tmp_path)],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)  # fmt: skip
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert f"error: the REST API cannot serve HTTPS: api.tls_key: {key} can be read or written by every user" in done.stderr
    assert "cellctl serving" not in done.stdout


async def test_a_hardware_api_beyond_loopback_without_tls_logs_the_warning_at_start(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The tests listen on loopback only: the address is made to count as the network's (is_loopback False),
    the service's mode as "hardware", and the API's port is held, so serve stops right after its start."""
    import cellctl.config.api as api_module

    monkeypatch.setattr(api_module, "is_loopback", lambda host: False)
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        config = sim_config(api={"port": held.getsockname()[1]})
        service = await build_service(config, workdir=tmp_path)
        service.config = service.config.model_copy(update={"mode": "hardware"})
        with caplog.at_level(logging.WARNING, logger="cellctl"), pytest.raises(ServiceError, match="cannot listen"):
            await service.serve()
    said = [r.getMessage() for r in caplog.records if "travel in clear" in r.getMessage()]
    assert said == [config.api.plain_http_warning()] and said[0] is not None, caplog.text
    assert 'set api.tls_cert and api.tls_key, or bind api.host = "127.0.0.1" behind a TLS proxy' in said[0]
