"""The OPC UA server's private key (opcua.private_key) damaged or unreadable: `serve` refuses in one line naming
the setting and the fix, no traceback; `config check --secrets` says the same line and exits 2."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from asyncua.crypto import uacrypto
from opcua_test_support import secure_config
from shared_support import run_cli

from cellctl.opcua.security import ServerCertificateError, ensure_certificate, server_certificate_problem
from cellctl.service import build_service
from cellctl.service.compose import ServiceError

pytestmark = pytest.mark.timeout(120)
SIM = Path(__file__).resolve().parents[2] / "config" / "sim.toml"
URI = "urn:cellctl:cell-1"
NOBODY = 65534


def _made(workdir: Path) -> tuple[Path, Path]:
    cert, key = workdir / "var" / "opcua" / "server-cert.der", workdir / "var" / "opcua" / "server-key.pem"
    assert ensure_certificate(cert, key, URI)
    return cert, key


async def _serve_refusal(workdir: Path) -> str:
    service = await build_service(secure_config(), workdir=workdir)
    with pytest.raises(ServiceError) as err:
        await service.start()
    return str(err.value)


def _check(capsys: pytest.CaptureFixture[str], workdir: Path) -> tuple[int, str]:
    text = SIM.read_text(encoding="utf-8")
    for old in ("\nport = 8080\n", "\nport = 5020\n"):
        text = text.replace(old, "\nport = 0\n")
    cfg = workdir / "cell.toml"
    cfg.write_text(text.replace("\nport = 4840 ", "\nport = 0 "), encoding="utf-8")
    rc, _, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(workdir))
    return rc, err


@pytest.mark.parametrize("damage", ["truncated", "not a key", "encrypted"])
async def test_a_damaged_private_key_is_refused_by_serve_and_check_in_one_line(
    damage: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, key = _made(tmp_path)
    good = key.read_bytes()
    if damage == "encrypted":
        from cryptography.hazmat.primitives import serialization

        pk = serialization.load_pem_private_key(good, password=None)
        key.write_bytes(pk.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                         serialization.BestAvailableEncryption(b"secret")))  # fmt: skip
    else:
        key.write_bytes(good[:200] if damage == "truncated" else b"hello\n")
    with pytest.raises((ValueError, TypeError)):  # asyncua itself cannot load it as the server will
        await uacrypto.load_private_key(str(key))
    said = await _serve_refusal(tmp_path)
    line = said.removeprefix("the OPC UA server cannot start: ")
    assert line.startswith(f"opcua.private_key {key} is not an unencrypted RSA private key"), said
    assert "delete it and its certificate to have new ones made" in line and "\n" not in said
    rc, err = _check(capsys, tmp_path)
    assert rc == 2 and line in err and "Traceback" not in err, err
    key.write_bytes(good)  # the right key back: both accept it
    assert _check(capsys, tmp_path)[0] == 0


@contextlib.contextmanager
def _as_nobody() -> Iterator[None]:
    """Act as an unprivileged user (root reads any file), back to root after; nothing if not root."""
    if os.geteuid() != 0:
        yield
        return
    os.setegid(NOBODY)
    os.seteuid(NOBODY)
    try:
        yield
    finally:
        os.seteuid(0)
        os.setegid(0)


async def test_an_unreadable_private_key_is_refused_naming_the_setting() -> None:
    with tempfile.TemporaryDirectory(prefix="cellctl-key-") as folder:  # traversable by the unprivileged user
        root = Path(folder)
        root.chmod(0o755)
        cert, key = _made(root)
        cert.parent.chmod(0o755)
        (root / "var").chmod(0o755)
        key.chmod(0o000)
        with _as_nobody():
            with pytest.raises(PermissionError):  # what asyncua's load would meet at start
                await uacrypto.load_private_key(str(key))
            problem = server_certificate_problem(cert, key)  # config check --secrets
            with pytest.raises(ServerCertificateError) as start:  # serve: the first thing its OPC UA start does
                ensure_certificate(cert, key, URI)
    said = str(start.value)
    assert said == problem and "\n" not in said, (said, problem)
    assert said.startswith(f"opcua.private_key {key} cannot be read (Permission denied); let the service's user read it")
