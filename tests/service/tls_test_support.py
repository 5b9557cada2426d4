"""A self-signed TLS certificate for 127.0.0.1 made with `cryptography`, for the API's HTTPS tests (its own peer)."""

from __future__ import annotations

import datetime
import ipaddress
import os
import ssl
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID


def _key_pem(key: ec.EllipticCurvePrivateKey, passphrase: bytes | None = None) -> bytes:
    crypt = serialization.BestAvailableEncryption(passphrase) if passphrase else serialization.NoEncryption()
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, crypt)


def self_signed(folder: Path, name: str = "api") -> tuple[Path, Path]:
    """``folder/<name>-cert.pem`` (CN cellctl-test, SAN 127.0.0.1 and localhost, valid a day) and its key
    ``folder/<name>-key.pem`` (mode 0600); returns (certificate, key)."""
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "cellctl-test")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder().subject_name(subject).issuer_name(subject).public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1")),
                                                    x509.DNSName("localhost")]), critical=False)
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(key, hashes.SHA256())
    )  # fmt: skip
    cert_path, key_path = folder / f"{name}-cert.pem", folder / f"{name}-key.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(_key_pem(key))
    os.chmod(key_path, 0o600)
    return cert_path, key_path


def other_key(path: Path, passphrase: bytes | None = None) -> Path:
    """A new EC key (not any certificate's) written to ``path`` (mode 0600), encrypted with ``passphrase`` if given."""
    path.write_bytes(_key_pem(ec.generate_private_key(ec.SECP256R1()), passphrase))
    os.chmod(path, 0o600)
    return path


def encrypted_copy(key_path: Path, passphrase: bytes) -> None:
    """Rewrite the PEM key at ``key_path`` encrypted with ``passphrase``."""
    key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    assert isinstance(key, ec.EllipticCurvePrivateKey)
    key_path.write_bytes(_key_pem(key, passphrase))


def trusting(cert: Path) -> ssl.SSLContext:
    """A client context that trusts ``cert`` alone (hostname checked), for httpx's ``verify``."""
    return ssl.create_default_context(cafile=str(cert))
