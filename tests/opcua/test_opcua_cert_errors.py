"""The OPC UA server's own certificate when it cannot be used: not DER (PEM text in a .der file, a damaged file)
or its folder not makeable. `serve` refuses in one line naming opcua.certificate / opcua.private_key and the fix
(and following that fix works); `config check --secrets` says the same; a PEM file named .pem is accepted."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from asyncua.crypto import uacrypto
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding
from opcua_test_support import secure_config
from shared_support import run_cli

from cellctl.opcua.security import certificate_uri, ensure_certificate
from cellctl.service import build_service
from cellctl.service.compose import ServiceError

pytestmark = pytest.mark.timeout(120)
SIM = Path(__file__).resolve().parents[2] / "config" / "sim.toml"
URI = "urn:cellctl:cell-1"


async def _refusal(workdir: Path, **opcua: str) -> str:
    """What `serve`'s start says for this workdir (the simulated cell, OPC UA as a hardware cell runs it)."""
    service = await build_service(secure_config(**opcua), workdir=workdir)
    with pytest.raises(ServiceError) as err:
        await service.start()
    return str(err.value)


def _check(capsys: pytest.CaptureFixture[str], workdir: Path, **paths: str) -> tuple[int, str]:
    text = SIM.read_text(encoding="utf-8").replace("\nport = 8080\n", "\nport = 0\n").replace("\nport = 5020\n", "\nport = 0\n")
    for key, value in paths.items():
        text = text.replace(f'\n{key} = "var/opcua/', f'\n{key} = "{value}" # ', 1)
    cfg = workdir / "cell.toml"
    cfg.write_text(text.replace("\nport = 4840 ", "\nport = 0 "), encoding="utf-8")
    rc, _, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(workdir))
    return rc, err


@pytest.mark.parametrize("damage", ["pem", "garbage"])
async def test_a_server_certificate_that_is_not_der_is_refused_with_the_fix(
    damage: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cert, key = tmp_path / "var" / "opcua" / "server-cert.der", tmp_path / "var" / "opcua" / "server-key.pem"
    assert ensure_certificate(cert, key, URI)
    der = cert.read_bytes()
    pem = x509.load_der_x509_certificate(der).public_bytes(Encoding.PEM)
    cert.write_bytes(pem if damage == "pem" else der[: len(der) // 2])
    with pytest.raises(ValueError):  # asyncua itself cannot load it as the server will (a .der name: DER)
        await uacrypto.load_certificate(str(cert))
    said = await _refusal(tmp_path)
    assert f"opcua.certificate {cert} is not a DER X.509 certificate" in said and "Traceback" not in said, said
    assert "\n" not in said and ("(it holds PEM text)" in said) == (damage == "pem")
    rc, err = _check(capsys, tmp_path)
    assert rc == 2 and said.removeprefix("the OPC UA server cannot start: ") in err, err
    if damage == "pem":  # the fix it names, run as given, makes the file one the server starts with
        command = said.split("convert it to DER: ", 1)[1].split(" (or name", 1)[0]
        subprocess.run(["sh", "-c", command], check=True, timeout=30, capture_output=True)
        assert cert.read_bytes() == der and _check(capsys, tmp_path)[0] == 0
        assert certificate_uri(cert) == URI


async def test_a_server_certificate_named_pem_is_made_and_read_as_pem(tmp_path: Path) -> None:
    cert, key = tmp_path / "server-cert.pem", tmp_path / "server-key.pem"
    assert ensure_certificate(cert, key, URI)
    assert cert.read_bytes().startswith(b"-----BEGIN CERTIFICATE-----")
    loaded = await uacrypto.load_certificate(str(cert))  # as asyncua loads the server's certificate
    assert certificate_uri(cert) == URI and URI in str(loaded.extensions)


async def test_a_certificate_folder_that_cannot_be_made_names_the_setting(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "bfile").write_text("x")
    said = await _refusal(tmp_path, certificate="bfile/server-cert.der", private_key="bfile/server-key.pem")
    key = tmp_path / "bfile" / "server-key.pem"
    assert "Errno" not in said and "File exists" not in said, said
    assert (f"opcua.private_key {key}: its folder {key.parent} cannot be created or written ({key.parent} is a file, "
            "not a folder); set opcua.certificate and opcua.private_key to files in a folder the service can write") in said
    rc, err = _check(capsys, tmp_path, certificate="bfile/server-cert.der", private_key="bfile/server-key.pem")
    assert rc == 2 and said.removeprefix("the OPC UA server cannot start: ") in err, err
