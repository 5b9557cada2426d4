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


def plant_chain(folder: Path, names: tuple[str, ...]) -> dict[str, Path]:
    """A plant CA (``ca.pem``) and two servers it signed: ``cell-chain.pem`` / ``cell-key.pem`` (DNS names ``names``,
    the chain leaf first, as [api] tls_cert takes it) and ``other-chain.pem`` / ``other-key.pem`` (the same names)."""
    now = datetime.datetime.now(datetime.timezone.utc)

    def issue(cn: str, issuer: x509.Name | None, signer: ec.EllipticCurvePrivateKey | None, ca: bool) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
        key = ec.generate_private_key(ec.SECP256R1())
        subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])
        b = (x509.CertificateBuilder().subject_name(subject).issuer_name(issuer or subject).public_key(key.public_key())
             .serial_number(x509.random_serial_number())
             .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=1))
             .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True))  # fmt: skip
        if not ca:
            b = b.add_extension(x509.SubjectAlternativeName([x509.DNSName(n) for n in names]), critical=False)
        return b.sign(signer or key, hashes.SHA256()), key

    ca, ca_key = issue("plant CA", None, None, True)
    pem = lambda c: c.public_bytes(serialization.Encoding.PEM)  # noqa: E731
    out = {"ca": folder / "ca.pem"}
    out["ca"].write_bytes(pem(ca))
    for name in ("cell", "other"):
        cert, key = issue(name, ca.subject, ca_key, False)
        out[name], out[f"{name}-key"] = folder / f"{name}-chain.pem", folder / f"{name}-key.pem"
        out[name].write_bytes(pem(cert) + pem(ca))
        out[f"{name}-key"].write_bytes(_key_pem(key))
        os.chmod(out[f"{name}-key"], 0o600)
    return out


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
