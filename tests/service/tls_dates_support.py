"""A plant CA and server certificates with chosen validity dates (relative to the OS clock), made with `cryptography`,
and a bare TLS server of Python's ssl module that serves one of them: for the tests of expired, not yet valid,
misnamed and misordered certificates."""

from __future__ import annotations

import datetime
import ipaddress
import os
import socket
import ssl
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

NOW = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)


def utc(when: datetime.datetime) -> str:
    """A date as the service's messages write it."""
    return when.strftime("%Y-%m-%d %H:%M UTC")


def _pem(cert: x509.Certificate) -> bytes:
    return cert.public_bytes(serialization.Encoding.PEM)


def issue(folder: Path, name: str, start: datetime.datetime, end: datetime.datetime, *,
          names: tuple[str, ...] = ("127.0.0.1", "localhost"), ca_first: bool = False) -> dict[str, Path]:  # fmt: skip
    """``folder/<name>-ca.pem`` (a plant CA valid a year around now) and the server certificate it signed, valid from
    ``start`` to ``end`` for ``names`` (addresses or DNS names): ``<name>-chain.pem`` (the leaf first, then the CA; the CA
    first if ``ca_first``) and its key ``<name>-key.pem`` (mode 0600). Returns the paths by "ca", "chain", "key"."""
    ca_key, key = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"{name} plant CA")])
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number())
          .not_valid_before(NOW - datetime.timedelta(days=365)).not_valid_after(NOW + datetime.timedelta(days=365))
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
          .sign(ca_key, hashes.SHA256()))  # fmt: skip
    alt: list[x509.GeneralName] = []
    for n in names:
        try:
            alt.append(x509.IPAddress(ipaddress.ip_address(n)))
        except ValueError:
            alt.append(x509.DNSName(n))
    leaf = (x509.CertificateBuilder().subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
            .issuer_name(ca_name).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(start).not_valid_after(end)
            .add_extension(x509.SubjectAlternativeName(alt), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .sign(ca_key, hashes.SHA256()))  # fmt: skip
    out = {"ca": folder / f"{name}-ca.pem", "chain": folder / f"{name}-chain.pem", "key": folder / f"{name}-key.pem"}
    out["ca"].write_bytes(_pem(ca))
    out["chain"].write_bytes(_pem(ca) + _pem(leaf) if ca_first else _pem(leaf) + _pem(ca))
    out["key"].write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                             serialization.NoEncryption()))  # fmt: skip
    os.chmod(out["key"], 0o600)
    return out


@contextmanager
def tls_server(chain: Path, key: Path) -> Iterator[int]:
    """A TLS server of Python's ssl module on 127.0.0.1 (a port the OS picks, yielded) that completes handshakes with
    ``chain`` / ``key`` and closes each connection; OpenSSL does not look at the dates when it loads them."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.load_cert_chain(chain, key)
    listener = socket.create_server(("127.0.0.1", 0))
    listener.settimeout(0.2)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = listener.accept()
            except OSError:
                continue
            try:
                with ctx.wrap_socket(conn, server_side=True) as tls:
                    tls.settimeout(2.0)
                    tls.recv(1)
            except OSError:  # the client refused the certificate (ssl.SSLError is an OSError)
                pass
            finally:
                conn.close()

    thread = threading.Thread(target=serve, name="tls-server", daemon=True)
    thread.start()
    try:
        yield int(listener.getsockname()[1])
    finally:
        stop.set()
        thread.join(timeout=5.0)
        listener.close()


def verify_failure(port: int, ca: Path, host: str = "127.0.0.1") -> ssl.SSLCertVerificationError:
    """What Python's ssl client (trusting ``ca``, checking ``host``) says of the server on ``port``."""
    ctx = ssl.create_default_context(cafile=str(ca))
    with socket.create_connection(("127.0.0.1", port), timeout=5.0) as raw:
        try:
            with ctx.wrap_socket(raw, server_hostname=host):
                pass
        except ssl.SSLCertVerificationError as err:
            return err
    raise AssertionError("the client accepted the certificate")
