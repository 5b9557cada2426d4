"""The OPC UA server's certificate, its users and what each may do; the caller of a method call.

asyncua hands a method callback no session, so the permission check (which sees the user of every
request, on the connection's own task, just before the request runs) remembers the caller in a
context variable the callbacks read: :func:`caller`.
"""

from __future__ import annotations

import contextlib
import contextvars
import hmac
import ipaddress
import logging
import os
import socket
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.crypto import cert_gen, uacrypto
from asyncua.crypto.permission_rules import SimpleRoleRuleset, User, UserRole
from asyncua.ua.ua_binary import struct_from_binary
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.hazmat.primitives.serialization import Encoding
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from cellctl.config.api import open_to_everyone
from cellctl.config.certificates import certificate_dates
from cellctl.config.opcua import OpcUaConfig, OpcUaUser
from cellctl.folders import folder_problem

log = logging.getLogger(__name__)

CERT_VALID_DAYS = 3650
CERT_BACKDATE = timedelta(days=1)
"""A certificate the server makes is valid from this long before it was made: a clock stepped back after the first start
(NTP, chrony's makestep, a flat RTC battery's day) does not make it "not valid yet"."""


@dataclass
class CellUser(User):
    """An authenticated OPC UA user; ``may_call``: operator (methods) or viewer (reads and subscriptions)."""

    may_call: bool = False


_caller: contextvars.ContextVar[CellUser | None] = contextvars.ContextVar("opcua_caller", default=None)
_x509_token: contextvars.ContextVar[bytes | None] = contextvars.ContextVar("opcua_x509_token", default=None)
"""The certificate of the X509 identity token whose signature asyncua has just verified, for the ``get_user`` call
that follows it in the same ActivateSession (asyncua passes the channel's certificate for the other token types)."""


def caller() -> str:
    """The name of the user whose method call is running (for the audit log)."""
    user = _caller.get()
    return "opcua:unknown" if user is None or not user.name else user.name


VIEWER_METHODS = frozenset({ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
                            ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh2)})  # fmt: skip
"""The standard methods that change nothing in the cell (they replay the retained alarms): viewers may call them."""


def called_methods(body: Any) -> list[ua.NodeId] | None:
    """The MethodIds of a Call request (its body not yet decoded, as asyncua checks it); None if it does not decode."""
    try:
        params = body if isinstance(body, ua.CallParameters) else struct_from_binary(ua.CallParameters, body.copy())
    except Exception:  # a malformed request: refused here, and asyncua answers it with its own error
        return None
    return [m.MethodId for m in params.MethodsToCall or []]


class CellRuleset(SimpleRoleRuleset):
    """Operators may call methods; viewers read, browse, subscribe and call the methods that change nothing
    (:data:`VIEWER_METHODS` and the cell's own added with :meth:`allow_viewers`); nobody writes the address space."""

    def __init__(self) -> None:
        super().__init__()
        self._call = ua.NodeId(ua.ObjectIds.CallRequest_Encoding_DefaultBinary)
        self._write = ua.NodeId(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary)
        self._viewer_methods: set[ua.NodeId] = set(VIEWER_METHODS)

    def allow_viewers(self, *methods: ua.NodeId) -> None:
        """Let viewers call these methods too (the cell's read-only ones, known once its namespace is registered)."""
        self._viewer_methods.update(methods)

    def check_validity(self, user: Any, action_type_id: ua.NodeId, body: Any) -> bool:
        if not isinstance(user, CellUser):
            return False
        _caller.set(user)
        if action_type_id == self._write:
            return False
        if action_type_id == self._call:
            return user.may_call or self._read_only_call(body)
        return bool(super().check_validity(user, action_type_id, body))

    def _read_only_call(self, body: Any) -> bool:
        methods = called_methods(body)
        return bool(methods) and all(m in self._viewer_methods for m in methods or ())


class CellUserManager:
    """Password users (compared in constant time), certificate users (by their DER), anonymous if allowed.

    asyncua calls :meth:`get_user` with a certificate for every token type: the X509 identity token's (its
    signature verified) or else the secure channel's (b"" over policy None). Only the former names a certificate
    user, so :meth:`watch` must see the server's token check; unwatched, any certificate counts as a token's.
    """

    def __init__(self, passwords: dict[str, tuple[str, bool]], certificates: dict[bytes, tuple[str, bool]],
                 *, allow_anonymous: bool) -> None:  # fmt: skip
        self._passwords = passwords
        self._certificates = certificates
        self._anonymous = allow_anonymous
        self._watching = False

    def watch(self, iserver: Any) -> None:
        """Follow ``iserver``'s X509 identity token checks (asyncua's InternalServer.verify_x509_token), so that a
        channel certificate under an anonymous token is told from a certificate user's token."""
        verify = iserver.verify_x509_token

        def verified(isession: Any, token: Any, signature: Any) -> bytes:
            der: bytes = verify(isession, token, signature)
            _x509_token.set(der)  # read, and cleared, by the get_user that follows (no await between them)
            return der

        iserver.verify_x509_token = verified
        self._watching = True

    @classmethod
    def from_config(cls, cfg: OpcUaConfig, root: Path) -> CellUserManager:
        """Read every password and certificate now, relative files taken from ``root`` (``serve --workdir``);
        a missing one raises naming the user and the fix."""
        passwords: dict[str, tuple[str, bool]] = {}
        certificates: dict[bytes, tuple[str, bool]] = {}
        for u in cfg.users:
            if u.certificate is not None:
                certificates[user_certificate(u, root)] = (u.name, u.role == "operator")
            else:
                passwords[u.name] = (u.secret(root), u.role == "operator")
        return cls(passwords, certificates, allow_anonymous=cfg.allow_anonymous)

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> CellUser | None:  # fmt: skip
        if username is not None:
            known = self._passwords.get(username)
            if known is None or password is None or not hmac.compare_digest(known[0].encode(), password.encode()):
                log.warning("OPC UA: user %r refused (unknown user or wrong password)", username)
                return None
            return CellUser(role=UserRole.User, name=username, may_call=known[1])
        token_der = _x509_token.get()
        _x509_token.set(None)
        der = certificate if certificate is None or isinstance(certificate, bytes) else certificate.public_bytes(Encoding.DER)
        if der and (not self._watching or der == token_der):  # an X509 identity token: its user or nobody
            who = self._certificates.get(der)
            if who is None:
                log.warning("OPC UA: a certificate user not in opcua.users was refused")
                return None
            return CellUser(role=UserRole.User, name=who[0], may_call=who[1])
        if self._anonymous:  # an anonymous token; its certificate, if any, is the secure channel's
            return CellUser(role=UserRole.User, name="opcua-anonymous", may_call=True)
        log.warning("OPC UA: an anonymous session was refused (opcua.allow_anonymous = false)")
        return None


def user_certificate(user: OpcUaUser, root: Path) -> bytes:
    """A certificate user's X.509 certificate (DER bytes), its path taken from ``root``; ValueError naming the user."""
    assert user.certificate is not None
    path = user.certificate if user.certificate.is_absolute() else root / user.certificate
    try:
        data = path.read_bytes()
        cert = x509.load_der_x509_certificate(data) if path.suffix.lower() == ".der" else x509.load_pem_x509_certificate(data)
    except (OSError, ValueError) as err:
        raise ValueError(f"opcua.users '{user.name}': certificate {path} cannot be read ({err}); give the "
                         "user's X.509 certificate as a DER (.der) or PEM file") from None
    return cert.public_bytes(Encoding.DER)


def trusted_clients_problem(folder: Path) -> str | None:
    """Why ``folder`` cannot be the trusted client certificates' folder (opcua.trusted_clients), or None."""
    if folder.is_dir() and any(folder.iterdir()):
        return None
    return (f"opcua.trusted_clients: {folder} is not a folder holding the trusted client certificates; put each "
            "client's certificate (DER) there or remove the setting")


def file_problems(cfg: OpcUaConfig, root: Path) -> list[str]:
    """What the server would refuse at start among the files it reads (the certificate users', the trusted
    clients' folder, its own certificate or the folders to make it in), paths taken from ``root`` as ``serve --workdir`` takes them; [] when none."""
    problems: list[str] = []
    for u in cfg.users:
        if u.certificate is not None:
            try:
                user_certificate(u, root)
            except ValueError as err:
                problems.append(str(err))
    if cfg.trusted_clients is not None:
        folder = cfg.trusted_clients if cfg.trusted_clients.is_absolute() else root / cfg.trusted_clients
        if (problem := trusted_clients_problem(folder)) is not None:
            problems.append(problem)
    cert, key = (p if p.is_absolute() else root / p for p in (cfg.certificate, cfg.private_key))
    if (problem := server_certificate_problem(cert, key)) is not None:
        problems.append(problem)
    return problems


class ServerCertificateError(ValueError):
    """The server's certificate (opcua.certificate) or key (opcua.private_key) cannot be read or made; names the fix."""


class CertificateNotValidYet(ServerCertificateError):
    """opcua.certificate starts after this computer's clock: the clock stands behind (at boot, before NTP), so a start
    once it is right succeeds (``serve`` exits 1, not 2)."""


def _folder_message(field: str, path: Path, why: str) -> str:
    return (f"{field} {path}: its folder {path.parent} cannot be created or written ({why}); set opcua.certificate and "
            "opcua.private_key to files in a folder the service can write (e.g. /var/lib/cellctl/opcua/server-cert.der"
            " and server-key.pem), or create that folder for the service's user")


def _writable_folder_problem(folder: Path) -> str | None:
    """Why the service could not write a file into ``folder`` (creating it if absent) now; None if it could."""
    if (why := folder_problem(folder)) is not None:
        return why
    if folder.is_dir() and not os.access(folder, os.W_OK | os.X_OK):
        return f"no right to write in {folder}"
    return None


def server_certificate_problem(cert_path: Path, key_path: Path) -> str | None:
    """What :func:`ensure_certificate` and :func:`certificate_uri` would refuse at start (dry run); None if nothing."""
    if cert_path.is_file() and key_path.is_file():
        try:
            check_server_certificate_dates(cert_path, load_server_certificate(cert_path))
            load_server_private_key(key_path)
        except ServerCertificateError as err:
            return str(err)
        return None
    for field, path in (("opcua.private_key", key_path), ("opcua.certificate", cert_path)):  # ensure_certificate's order
        if (why := _writable_folder_problem(path.parent)) is not None:
            return _folder_message(field, path, why)
    return None


def _is_pem_name(path: Path) -> bool:
    """asyncua's rule (``Server.load_certificate``): a file whose name ends in .pem is PEM, any other DER."""
    return path.suffix.lower() == ".pem"


def load_server_certificate(cert_path: Path) -> x509.Certificate:
    """The server's certificate as asyncua will load it (PEM if named .pem, else DER); ServerCertificateError if not."""
    try:
        data = cert_path.read_bytes()
    except OSError as err:
        raise ServerCertificateError(f"opcua.certificate {cert_path} cannot be read ({err.strerror or err}); let the "
                                     "service's user read it, or delete it and its key to have new ones made") from None
    try:
        cert = x509.load_pem_x509_certificate(data) if _is_pem_name(cert_path) else uacrypto.x509_from_der(data)
    except (ValueError, IndexError):  # IndexError: a truncated DER chain
        cert = None
    if cert is not None:
        return cert
    if _is_pem_name(cert_path):
        raise ServerCertificateError(f"opcua.certificate {cert_path} is not a PEM X.509 certificate; give the server's "
                                     "certificate, or delete it and its key to have new ones made") from None
    pem = b"-----BEGIN CERTIFICATE-----" in data
    raise ServerCertificateError(
        f"opcua.certificate {cert_path} is not a DER X.509 certificate" + (" (it holds PEM text)" if pem else "")
        + f"; convert it to DER: openssl x509 -in {cert_path} -outform der -out {cert_path}.new && mv {cert_path}.new "
        f"{cert_path} (or name a PEM file *.pem), or delete it and its key to have new ones made") from None


def check_server_certificate_dates(cert_path: Path, cert: x509.Certificate) -> None:
    """ServerCertificateError naming opcua.certificate and its dates if it is not valid now (clients refuse it); a
    warning logged when it expires within EXPIRY_WARNING_DAYS."""
    fix = (f"give a renewed certificate (the same application URI and key), or delete {cert_path} and its key to have "
           "new ones made (and give the new certificate to the plant's clients)")
    now = datetime.now(timezone.utc)
    problem, warning = certificate_dates(cert, f"opcua.certificate {cert_path}", fix, now=now)
    if problem is not None:
        raise (CertificateNotValidYet if now < cert.not_valid_before_utc else ServerCertificateError)(problem)
    if warning is not None:
        log.warning("%s", warning)


def load_server_private_key(key_path: Path) -> rsa.RSAPrivateKey:
    """The server's key as asyncua will load it (PEM if named .pem, else DER, no password); ServerCertificateError if not."""
    fix = "or delete it and its certificate to have new ones made"
    try:
        data = key_path.read_bytes()
    except OSError as err:
        raise ServerCertificateError(f"opcua.private_key {key_path} cannot be read ({err.strerror or err}); let the "
                                     f"service's user read it (chmod 600, owned by that user), {fix}") from None
    with contextlib.suppress(OSError):  # one that cannot be looked at is said below, when it cannot be read
        if (exposed := open_to_everyone(key_path, key_path.stat())) is not None:  # the token files' rule
            raise ServerCertificateError(f"opcua.private_key {exposed}")
    kind = "PEM" if _is_pem_name(key_path) else "DER"
    try:
        load = serialization.load_pem_private_key if kind == "PEM" else serialization.load_der_private_key
        key = load(data, password=None)
    except (ValueError, TypeError):  # TypeError: the key is encrypted (asyncua is given no password)
        key = None
    if not isinstance(key, rsa.RSAPrivateKey):
        raise ServerCertificateError(f"opcua.private_key {key_path} is not an unencrypted RSA private key ({kind}, "
                                     f"as its name {key_path.name!r} says); give the certificate's key, {fix}")
    return key


def ensure_certificate(cert_path: Path, key_path: Path, application_uri: str) -> bool:
    """Create the server's self-signed certificate and key if either is absent; True if it created them.
    Existing ones are checked: ServerCertificateError naming the setting if the certificate is not valid now (its
    dates) or the key cannot be loaded.

    RSA 2048 / SHA-256, SubjectAltName the application URI, this host's name, localhost and
    127.0.0.1, valid from a day before now (:data:`CERT_BACKDATE`) for ten years; the key is written readable by the
    service's user only.
    """
    if cert_path.is_file() and key_path.is_file():
        check_server_certificate_dates(cert_path, load_server_certificate(cert_path))
        load_server_private_key(key_path)  # asyncua's own load would end the start in a traceback
        return False
    key = cert_gen.generate_private_key()
    host = socket.gethostname()
    names: list[x509.GeneralName] = [x509.UniformResourceIdentifier(application_uri), x509.DNSName(host),
                                     x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]  # fmt: skip
    cert = self_signed_certificate(key, f"cellctl {host}", names, datetime.now(timezone.utc))
    for field, path in (("opcua.private_key", key_path), ("opcua.certificate", cert_path)):
        try:
            if path is key_path:
                _write_new(path, cert_gen.dump_private_key_as_pem(key), 0o600)  # the service's user only
            else:
                _write_new(path, cert.public_bytes(Encoding.PEM if _is_pem_name(path) else Encoding.DER), 0o644)
        except OSError as err:
            why = _writable_folder_problem(path.parent) or err.strerror or str(err)
            raise ServerCertificateError(_folder_message(field, path, why)) from None
    return True


def self_signed_certificate(
    key: rsa.RSAPrivateKey, common_name: str, names: list[x509.GeneralName], now: datetime
) -> x509.Certificate:
    """The server's self-signed application certificate (OPC 10000-6 6.2.2), as asyncua's
    ``cert_gen.generate_self_signed_app_certificate`` makes it (subject CN and O=cellctl, the same extensions and key
    usage, server and client authentication) but valid from ``now`` (UTC) - CERT_BACKDATE to ``now`` + CERT_VALID_DAYS
    (asyncua's starts at the instant it is made and takes no start)."""
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name),
                         x509.NameAttribute(NameOID.ORGANIZATION_NAME, "cellctl")])  # fmt: skip
    serial = x509.random_serial_number()
    key_id = x509.SubjectKeyIdentifier.from_public_key(key.public_key())
    usage = x509.KeyUsage(digital_signature=True, content_commitment=True, key_encipherment=True, data_encipherment=True,
                          key_agreement=False, key_cert_sign=True, crl_sign=False, encipher_only=False,
                          decipher_only=False)  # fmt: skip
    builder = (
        x509.CertificateBuilder().subject_name(subject).issuer_name(subject).serial_number(serial)
        .not_valid_before(now - CERT_BACKDATE).not_valid_after(now + timedelta(days=CERT_VALID_DAYS))
        .public_key(key.public_key())
        .add_extension(key_id, critical=False)
        .add_extension(x509.AuthorityKeyIdentifier(key_id.digest, [x509.DirectoryName(subject)], serial), critical=False)
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=False)
        .add_extension(usage, critical=False)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                       critical=False)
    )  # fmt: skip
    return builder.sign(private_key=key, algorithm=hashes.SHA256())


def _write_new(path: Path, data: bytes, mode: int) -> None:
    """Write ``data`` to a new file at ``path`` (mode ``mode``, the umask applies), its folders created. A file
    already there is removed first, so that its mode (say 0644 on a key) and owner do not carry over."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileNotFoundError):
        path.unlink()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def certificate_uri(cert_path: Path) -> str | None:
    """The application URI in a certificate's SubjectAltName (None if it has none); ServerCertificateError if unreadable."""
    cert = load_server_certificate(cert_path)
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return None
    uris = san.get_values_for_type(x509.UniformResourceIdentifier)
    return uris[0] if uris else None
