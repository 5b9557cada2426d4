"""The OPC UA server's certificate (opcua.certificate) outside its validity, expired or not yet valid by the OS
clock, refuses `serve` and `config check --secrets` naming the setting and the dates; one that expires within 30 days
is warned about and served. The certificate is the one the server made, signed again with its own key and URI and
other dates (as a renewal would), read back the way asyncua loads it, and judged by asyncua's own certificate check."""

from __future__ import annotations

import datetime
import logging
from pathlib import Path

import pytest
from asyncua.crypto import uacrypto
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.hazmat.primitives.serialization import Encoding
from opcua_test_support import secure_config
from shared_support import run_cli

from cellctl.opcua.security import certificate_uri, ensure_certificate
from cellctl.service import build_service
from cellctl.service.compose import ServiceError

pytestmark = pytest.mark.timeout(120)
SIM = Path(__file__).resolve().parents[2] / "config" / "sim.toml"
URI = "urn:cellctl:cell-1"
NOW = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)
DAY = datetime.timedelta(days=1)


def _utc(when: datetime.datetime) -> str:
    return when.strftime("%Y-%m-%d %H:%M UTC")


async def _redated(workdir: Path, start: datetime.datetime, end: datetime.datetime) -> tuple[Path, bool]:
    """The server's certificate (made at var/opcua/ as serve makes it), re-signed with its key valid ``start``-``end``;
    and whether asyncua's own check of a certificate (uacrypto.check_certificate, which only logs) finds a fault."""
    cert, key = workdir / "var" / "opcua" / "server-cert.der", workdir / "var" / "opcua" / "server-key.pem"
    assert ensure_certificate(cert, key, URI)
    made = x509.load_der_x509_certificate(cert.read_bytes())
    private = serialization.load_pem_private_key(key.read_bytes(), password=None)
    assert isinstance(private, rsa.RSAPrivateKey)
    b = (x509.CertificateBuilder().subject_name(made.subject).issuer_name(made.issuer).public_key(made.public_key())
         .serial_number(x509.random_serial_number()).not_valid_before(start).not_valid_after(end))  # fmt: skip
    for ext in made.extensions:
        b = b.add_extension(ext.value, critical=ext.critical)
    cert.write_bytes(b.sign(private, hashes.SHA256()).public_bytes(Encoding.DER))
    loaded = await uacrypto.load_certificate(str(cert))  # as the server loads it
    assert loaded.not_valid_before_utc == start and loaded.not_valid_after_utc == end and certificate_uri(cert) == URI
    return cert, uacrypto.check_certificate(loaded, URI)


def _check(capsys: pytest.CaptureFixture[str], workdir: Path) -> tuple[int, str, str]:
    text = SIM.read_text(encoding="utf-8").replace("\nport = 8080\n", "\nport = 0\n").replace("\nport = 5020\n", "\nport = 0\n")
    cfg = workdir / "cell.toml"
    cfg.write_text(text.replace("\nport = 4840 ", "\nport = 0 "), encoding="utf-8")
    return run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(workdir))


@pytest.mark.parametrize(
    ("start", "end", "said"),
    [(NOW - 400 * DAY, NOW - 35 * DAY, "has expired"), (NOW + 30 * DAY, NOW + 400 * DAY, "is not valid yet")],
    ids=["expired", "not yet valid"],
)
async def test_a_server_certificate_outside_its_dates_is_refused_with_them(
    start: datetime.datetime, end: datetime.datetime, said: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:  # fmt: skip
    cert, faulty = await _redated(tmp_path, start, end)
    assert faulty  # asyncua finds it out of date too
    line = f"opcua.certificate {cert} {said} (valid from {_utc(start)} to {_utc(end)}; now "
    service = await build_service(secure_config(), workdir=tmp_path)
    with pytest.raises(ServiceError) as err:
        await service.start()
    refusal = str(err.value)
    assert refusal.startswith(f"the OPC UA server cannot start: {line}") and "\n" not in refusal, refusal
    assert f"or delete {cert} and its key to have new ones made" in refusal, refusal
    rc, out, errs = _check(capsys, tmp_path)
    assert rc == 2 and refusal.removeprefix("the OPC UA server cannot start: ") in errs, out + errs


async def test_a_server_certificate_expiring_within_30_days_is_warned_and_served(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:  # fmt: skip
    end = NOW + 10 * DAY + datetime.timedelta(hours=1)
    cert, faulty = await _redated(tmp_path, NOW - 355 * DAY, end)
    assert not faulty  # still valid for asyncua
    warning = f"opcua.certificate {cert} expires in 10 day(s), on {_utc(end)}"
    rc, out, errs = _check(capsys, tmp_path)
    assert rc == 0 and out.startswith("OK: ") and warning in errs, out + errs
    service = await build_service(secure_config(), workdir=tmp_path)
    with caplog.at_level(logging.WARNING, logger="cellctl"):
        await service.start()
    try:
        assert service.opcua_server is not None and service.opcua_server.port > 0
    finally:
        await service.stop()
    assert any(r.getMessage().startswith(warning) for r in caplog.records), caplog.text
