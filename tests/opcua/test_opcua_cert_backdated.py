"""The OPC UA server's self-made certificate is valid from a day before it was made (a clock stepped back after the
first start does not make it "not valid yet"), and is otherwise what asyncua's own generator makes for the same key and
names: subject, issuer, SubjectAltName, key usage, extended key usage, basic constraints, key identifiers; ten years.
An existing certificate is kept as it is, whatever its dates.

Peers: the certificate file parsed by `cryptography`, asyncua's `cert_gen.generate_self_signed_app_certificate` (the
reference of the fields) and `uacrypto.check_certificate` (asyncua's own check of dates, URI and host name)."""

from __future__ import annotations

import datetime as dt
import socket
from pathlib import Path

from asyncua.crypto import cert_gen, uacrypto
from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.hazmat.primitives.serialization import Encoding
from cryptography.x509.oid import ExtendedKeyUsageOID

from cellctl.opcua.security import ensure_certificate

URI = "urn:cellctl:cell-1"
SLACK = dt.timedelta(minutes=1)


def test_the_made_certificate_starts_a_day_back_and_has_asyncuas_fields(tmp_path: Path) -> None:
    cert_path, key_path = tmp_path / "opcua" / "server-cert.der", tmp_path / "opcua" / "server-key.pem"
    before = dt.datetime.now(dt.timezone.utc)
    assert ensure_certificate(cert_path, key_path, URI)
    after = dt.datetime.now(dt.timezone.utc)
    made = x509.load_der_x509_certificate(cert_path.read_bytes())
    day = dt.timedelta(days=1)
    assert before - day - SLACK <= made.not_valid_before_utc <= after - day, made.not_valid_before_utc
    assert before + dt.timedelta(days=3650) - SLACK <= made.not_valid_after_utc <= after + dt.timedelta(days=3650)
    host = socket.gethostname()
    assert not uacrypto.check_certificate(made, URI, host)  # asyncua finds no fault: dates, URI, host name

    key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    assert isinstance(key, rsa.RSAPrivateKey) and key.key_size == 2048
    san = made.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    reference = cert_gen.generate_self_signed_app_certificate(
        key, f"cellctl {host}", {"organizationName": "cellctl"}, list(san),
        extended=[ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH], days=3650,
    )  # fmt: skip
    assert made.subject == reference.subject and made.issuer == reference.issuer == made.subject
    assert made.signature_hash_algorithm is not None and made.signature_hash_algorithm.name == "sha256"
    assert [str(n.value) for n in san] == [URI, host, "localhost", "127.0.0.1"]
    ours = {e.oid: e for e in made.extensions}
    theirs = {e.oid: e for e in reference.extensions}
    assert set(ours) == set(theirs)
    for oid, ext in theirs.items():
        if isinstance(ext.value, x509.AuthorityKeyIdentifier):  # names the serial number, which is random
            mine = ours[oid].value
            assert mine.key_identifier == ext.value.key_identifier
            assert mine.authority_cert_issuer == ext.value.authority_cert_issuer
            assert mine.authority_cert_serial_number == made.serial_number
        else:
            assert ours[oid] == ext, oid

    # An existing certificate is kept, byte for byte, even one asyncua made starting the instant it was made.
    cert_path.write_bytes(reference.public_bytes(Encoding.DER))
    kept = cert_path.read_bytes()
    assert not ensure_certificate(cert_path, key_path, URI)
    assert cert_path.read_bytes() == kept
