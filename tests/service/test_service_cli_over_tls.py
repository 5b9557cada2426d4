"""The CLI reaches a service that serves HTTPS: from the cell's own configuration it trusts exactly the certificate
the service serves (whatever name it was issued for); with ``--url`` it trusts ``--ca``; an untrusted certificate,
plain HTTP to the TLS port or an unreadable certificate each say what to do. The peers: `cellctl serve` in another
process, the CLI as a subprocess, and Python's ssl module as a second TLS server holding another certificate of the
same plant CA (which the pinned trust must refuse)."""

from __future__ import annotations

import os
import socket
import ssl
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from service_test_support import free_port, sim_toml, start_serve, wait_up
from tls_test_support import plant_chain

from cellctl.client import ServiceError, pinned_to, trusting_ca

pytestmark = pytest.mark.timeout(180)
TLS_LINES = 'tls_cert = "tls/cell-chain.pem"\ntls_key = "tls/cell-key.pem"\n'  # relative: from serve --workdir
NAMES = ("cell.plant.example", "localhost")  # not 127.0.0.1: the derived URL's host is not among its names


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("SSL_CERT_FILE", "SSL_CERT_DIR", "CELLCTL_URL", "CELLCTL_WORKDIR")}
    return subprocess.run([sys.executable, "-m", "cellctl", *args], env=env, cwd=cwd, capture_output=True, text=True, timeout=60)


def test_the_cli_reaches_a_tls_service_by_its_configuration_or_by_url_and_ca(tmp_path: Path) -> None:
    (tmp_path / "tls").mkdir()
    pki = plant_chain(tmp_path / "tls", NAMES)
    port = free_port()
    text = sim_toml(port).replace("\ncycle_wait_max_s = 600.0\n", "\ncycle_wait_max_s = 600.0\n" + TLS_LINES, 1)
    assert TLS_LINES in text
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text)
    proc = start_serve(cfg, tmp_path)
    try:
        wait_up(f"https://localhost:{port}", proc, tmp_path, verify=trusting_ca(pki["ca"]))  # by the name localhost
        # on the cell's computer, from serve's workdir: the configuration's [api] over https, its own certificate trusted
        own = _cli("status", "--config", str(cfg), cwd=tmp_path)
        assert own.returncode == 0 and own.stdout.startswith("state "), own.stdout + own.stderr
        # from elsewhere: the URL and the plant's CA (the certificate's name checked: localhost is one of its names)
        by_ca = _cli("status", "--config", str(cfg), "--url", f"https://localhost:{port}", "--ca", str(pki["ca"]), cwd=tmp_path)
        assert by_ca.returncode == 0 and by_ca.stdout.startswith("state "), by_ca.stdout + by_ca.stderr
        untrusted = _cli("status", "--config", str(cfg), "--url", f"https://127.0.0.1:{port}", cwd=tmp_path)
        assert untrusted.returncode == 1 and "CERTIFICATE_VERIFY_FAILED" in untrusted.stderr, untrusted.stderr
        assert "give --ca with the PEM of the CA that signed it" in untrusted.stderr, untrusted.stderr
        plain = _cli("status", "--config", str(cfg), "--url", f"http://127.0.0.1:{port}", cwd=tmp_path)
        assert plain.returncode == 1 and "use https://" in plain.stderr, plain.stderr
        elsewhere = tmp_path / "elsewhere"
        elsewhere.mkdir()
        lost = _cli("status", "--config", str(cfg), cwd=elsewhere)  # tls/cell-chain.pem is not under this folder
        assert lost.returncode == 1 and "api.tls_cert" in lost.stderr and "--workdir" in lost.stderr, lost.stderr
    finally:
        proc.terminate()
        assert proc.wait(timeout=30) == 0, (tmp_path / "service.log").read_text()


@pytest.fixture
def two_servers(tmp_path: Path) -> Iterator[tuple[dict[str, Path], int, int]]:
    """The cell's and another server of the same plant CA, each a TLS listener on loopback."""
    pki = plant_chain(tmp_path, NAMES)
    listeners = []
    for name in ("cell", "other"):
        ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        ctx.load_cert_chain(pki[name], pki[f"{name}-key"])
        sock = socket.create_server(("127.0.0.1", 0))
        listeners.append(sock)

        def serve(sock: socket.socket = sock, ctx: ssl.SSLContext = ctx) -> None:
            while True:
                try:
                    conn, _ = sock.accept()
                except OSError:
                    return
                try:
                    ctx.wrap_socket(conn, server_side=True).close()
                except (OSError, ssl.SSLError):
                    conn.close()

        threading.Thread(target=serve, daemon=True).start()
    yield pki, listeners[0].getsockname()[1], listeners[1].getsockname()[1]
    for sock in listeners:
        sock.close()


def _handshake(ctx: ssl.SSLContext, port: int) -> None:
    with socket.create_connection(("127.0.0.1", port), timeout=5.0) as raw, ctx.wrap_socket(raw, server_hostname="127.0.0.1"):
        pass


def test_the_pinned_trust_takes_the_services_own_certificate_and_no_other_of_its_ca(two_servers: tuple[dict[str, Path], int, int]) -> None:
    pki, cell_port, other_port = two_servers
    _handshake(pinned_to(pki["cell"]), cell_port)
    with pytest.raises(ssl.SSLCertVerificationError):  # the plant CA signed it, but it is not the service's certificate
        _handshake(pinned_to(pki["cell"]), other_port)
    with pytest.raises(ssl.SSLCertVerificationError):  # --ca checks the name: 127.0.0.1 is not one of the certificate's
        _handshake(trusting_ca(pki["ca"]), cell_port)


def test_an_unusable_certificate_or_ca_file_names_it(tmp_path: Path) -> None:
    with pytest.raises(ServiceError, match=r"api.tls_cert .*missing.pem: cannot read"):
        pinned_to(tmp_path / "missing.pem")
    (tmp_path / "empty.pem").write_text("not a certificate\n")
    with pytest.raises(ServiceError, match=r"api.tls_cert .*empty.pem: no PEM certificate"):
        pinned_to(tmp_path / "empty.pem")
    with pytest.raises(ServiceError, match=r"--ca .*empty.pem: cannot use it"):
        trusting_ca(tmp_path / "empty.pem")
