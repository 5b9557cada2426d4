"""The OPC UA server's private key (opcua.private_key) as the API token files are kept: one that every user may
read or write is refused by `serve` and `config check --secrets`, naming the field and the chmod; and a key the
server makes where a file already stood is the service user's alone (the OS says the mode, asyncua loads it)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
from asyncua.crypto import uacrypto
from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat
from opcua_test_support import secure_config
from shared_support import free_port, run_cli

from cellctl.opcua.security import ensure_certificate, server_certificate_problem
from cellctl.service import build_service
from cellctl.service.compose import ServiceError

pytestmark = pytest.mark.timeout(120)
SIM = Path(__file__).resolve().parents[2] / "config" / "sim.toml"
URI = "urn:cellctl:cell-1"


def _pair(workdir: Path) -> tuple[Path, Path]:
    cert, key = workdir / "var" / "opcua" / "server-cert.der", workdir / "var" / "opcua" / "server-key.pem"
    assert ensure_certificate(cert, key, URI)
    return cert, key


def _check(capsys: pytest.CaptureFixture[str], workdir: Path) -> tuple[int, str]:
    """`cellctl config check --secrets` on config/sim.toml (its key var/opcua/server-key.pem) from ``workdir``."""
    text = SIM.read_text(encoding="utf-8")
    for default in ("\nport = 8080\n", "\nport = 5020\n", "\nport = 4840 "):
        assert text.count(default) == 1
        text = text.replace(default, default.replace(default.split()[-1], str(free_port())), 1)
    cfg = workdir / "cell.toml"
    cfg.write_text(text, encoding="utf-8")
    rc, _, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(workdir))
    return rc, err


@pytest.mark.parametrize("mode", [0o644, 0o604, 0o602], ids=["0644", "0604", "0602"])
async def test_a_server_key_every_user_may_read_or_write_is_refused(
    mode: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cert, key = _pair(tmp_path)
    os.chmod(key, mode)
    assert stat.S_IMODE(key.stat().st_mode) == mode  # the OS holds the mode the message must name
    said = f"opcua.private_key {key} can be read or written by every user (mode {mode:04o}); chmod 600 {key}"
    problem = server_certificate_problem(cert, key)
    assert problem is not None and said in problem, problem
    rc, err = _check(capsys, tmp_path)
    assert rc == 2 and said in err, err
    service = await build_service(secure_config(), workdir=tmp_path)
    with pytest.raises(ServiceError) as refused:
        await service.start()
    assert said in str(refused.value), refused.value
    assert service.stopped
    os.chmod(key, 0o640)  # the fix it names (or the service's group): accepted, and nothing else changed
    assert server_certificate_problem(cert, key) is None
    assert _check(capsys, tmp_path)[0] == 0


def test_a_new_key_where_a_world_readable_file_stood_is_the_service_users_alone(tmp_path: Path) -> None:
    cert, key = tmp_path / "opcua" / "server-cert.der", tmp_path / "opcua" / "server-key.pem"
    key.parent.mkdir()
    key.write_bytes(b"an old key, copied in with cp\n")
    os.chmod(key, 0o644)
    assert ensure_certificate(cert, key, URI)  # no certificate: a new pair, the key file written anew
    assert stat.S_IMODE(key.stat().st_mode) & 0o077 == 0, oct(key.stat().st_mode)
    assert key.stat().st_uid == os.getuid()
    assert server_certificate_problem(cert, key) is None


async def test_the_rewritten_key_is_the_certificates(tmp_path: Path) -> None:
    cert, key = tmp_path / "server-cert.der", tmp_path / "server-key.pem"
    key.write_bytes(b"stale")
    os.chmod(key, 0o666)
    assert ensure_certificate(cert, key, URI)
    loaded = await uacrypto.load_private_key(str(key))  # as asyncua's server loads it
    certificate = await uacrypto.load_certificate(str(cert))
    pub = (Encoding.DER, PublicFormat.SubjectPublicKeyInfo)
    assert loaded.public_key().public_bytes(*pub) == certificate.public_key().public_bytes(*pub)
    assert stat.S_IMODE(key.stat().st_mode) & 0o077 == 0
