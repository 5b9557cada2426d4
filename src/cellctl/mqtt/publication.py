"""MQTT publication of one cell, put together: outbox, bridge and publisher around the orchestrator.

The service builds it when ``[mqtt] enabled`` (:mod:`cellctl.service.compose`), starts it after
the orchestrator (its catch-up reads the recovered store) and stops it before the store closes.
Credentials and TLS files are read at :meth:`MqttPublication.start` (the TLS files loaded as the TLS client loads
them); one that cannot be used raises :class:`MqttSetupError` naming the field.
"""

from __future__ import annotations

import logging
import os
import re
import ssl
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

import aiomqtt

from cellctl.config.api import TokenUnavailable, open_to_everyone, read_secret
from cellctl.config.certificates import certificate_dates, key_certificate_index
from cellctl.config.mqtt import MqttConfig
from cellctl.mqtt.bridge import EventBridge
from cellctl.mqtt.outbox import Outbox
from cellctl.mqtt.publisher import MqttPublisher
from cellctl.mqtt.topics import CellTopics

if TYPE_CHECKING:
    from cellctl.cell.orchestrator import CellOrchestrator

log = logging.getLogger(__name__)

STOP_GRACE_S = 3.0  # at a stop, how long pending messages may still be sent while the broker answers
PASSWORD_FILE_MAX_BYTES = 4096
NEW_CLIENT_CERTIFICATE = "have the plant's CA issue a new client certificate, and restart the service"


class MqttSetupError(ValueError):
    """A credential or TLS file named in [mqtt] cannot be used; the message names the field and the fix."""


class MqttCertificateNotValidYet(MqttSetupError):
    """mqtt.tls.cert_file starts after this computer's clock: the clock stands behind (at boot, before NTP), so a start
    once it is right succeeds (``serve`` exits 1, not 2)."""


def _resolve(path: Path, workdir: Path) -> Path:
    return path if path.is_absolute() else workdir / path


def read_password(config: MqttConfig, workdir: Path) -> str | None:
    """The password from ``mqtt.password_file`` (None without one), checked as the API token files are."""
    if config.password_file is None:
        return None
    path = _resolve(config.password_file, workdir)
    try:
        with path.open("rb") as f:
            raw = f.read(PASSWORD_FILE_MAX_BYTES + 1)
    except OSError as err:
        raise MqttSetupError(f"mqtt.password_file {path}: cannot be read ({err.strerror or err}); "
                             "create it with the broker password on one line, readable by the service only") from None
    text = raw.decode("utf-8", errors="replace").strip()
    if not text or len(raw) > PASSWORD_FILE_MAX_BYTES or "\n" in text:
        raise MqttSetupError(f"mqtt.password_file {path}: must hold the password on one line (and nothing else)")
    try:  # the API token files' checks: not readable by every user, not short, a placeholder or a default
        return read_secret("mqtt", env=("password_env", None), file=("password_file", path), what="password")
    except TokenUnavailable as err:
        raise MqttSetupError(str(err)) from None


def tls_parameters(config: MqttConfig, workdir: Path) -> aiomqtt.TLSParameters | None:
    """aiomqtt's TLS settings from ``mqtt.tls``, every file loaded now as the TLS client loads it at connect (the CA
    file, the client certificate with its key), the client's key readable by the service only (as the password file)
    and the client certificate valid now."""
    tls = config.tls
    if tls is None:
        return None
    files: dict[str, str | None] = {}
    for field in ("ca_file", "cert_file", "key_file"):
        value = getattr(tls, field)
        if value is None:
            files[field] = None
            continue
        path = _resolve(value, workdir)
        if not path.is_file() or not os.access(path, os.R_OK):
            raise MqttSetupError(f"mqtt.tls.{field} {path}: not a readable file; give the path of the PEM file")
        if field == "key_file" and (exposed := open_to_everyone(path, path.stat())) is not None:  # the token files' rule
            raise MqttSetupError(f"mqtt.tls.key_file: {exposed}")
        files[field] = str(path)
    ca, cert, key = files["ca_file"], files["cert_file"], files["key_file"]
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)  # what paho's tls_set builds and loads at each connect
    try:
        context.load_verify_locations(cafile=ca)
    except (ssl.SSLError, OSError) as err:
        raise MqttSetupError(f"mqtt.tls.ca_file: {ca} holds no PEM certificate OpenSSL can load ({_reason(err)}); give "
                             "the PEM certificate of the CA that signed the broker's certificate") from None
    if cert is not None and key is not None:
        _load_client_pair(context, cert, key)
        _check_validity(cert)
    return aiomqtt.TLSParameters(ca_certs=ca, certfile=cert, keyfile=key)


class _PassphraseAsked(Exception):
    """OpenSSL asked for the client key's passphrase, which [mqtt] cannot give."""


def _no_passphrase() -> bytes:
    raise _PassphraseAsked  # never a prompt on the terminal (the service has none)


def _reason(err: Exception) -> str:
    """OpenSSL's words for a failed load, without the location in Python's C source."""
    if not isinstance(err, ssl.SSLError):
        return str(err)
    text = err.reason or (err.args[1] if len(err.args) > 1 else str(err))
    return "OpenSSL: " + re.sub(r"\s*\(_ssl\.c:\d+\)$", "", str(text))


def _load_client_pair(context: ssl.SSLContext, cert: str, key: str) -> None:
    """The client certificate and key loaded as TLS will; MqttSetupError naming the field at fault otherwise."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    try:
        context.load_cert_chain(cert, key, password=_no_passphrase)
        return
    except _PassphraseAsked:
        raise MqttSetupError(f"mqtt.tls.key_file: {key} is encrypted with a passphrase, which the service cannot be "
                             f"given; write it unencrypted (openssl pkey -in {key} -out new.pem), chmod 600") from None
    except (ssl.SSLError, OSError) as err:
        failure = err
    if isinstance(failure, ssl.SSLError) and failure.reason == "KEY_VALUES_MISMATCH":
        if key_certificate_index(cert, key):  # the key's certificate is in the file, but not first
            raise MqttSetupError(f"mqtt.tls.cert_file: {cert} holds the certificate of mqtt.tls.key_file {key}, but not "
                                 "first; put the client's own certificate first, the intermediate CA certificates "
                                 "after it") from None
        raise MqttSetupError(f"mqtt.tls.key_file: {key} is not the private key of mqtt.tls.cert_file {cert}; give the "
                             "certificate's own key") from None
    try:
        x509.load_pem_x509_certificate(Path(cert).read_bytes())
    except ValueError:
        raise MqttSetupError(f"mqtt.tls.cert_file: {cert} is not a PEM certificate ({_reason(failure)}); give the "
                             "client certificate the plant's CA issued, PEM") from None
    try:
        serialization.load_pem_private_key(Path(key).read_bytes(), password=None)
    except (ValueError, TypeError):
        raise MqttSetupError(f"mqtt.tls.key_file: {key} is not a PEM private key ({_reason(failure)}); give the "
                             "client certificate's own key, PEM, unencrypted") from None
    raise MqttSetupError(f"mqtt.tls.cert_file, mqtt.tls.key_file: {cert} and {key} cannot be used by TLS "
                         f"({_reason(failure)}); give the client certificate the plant's CA issued and its key") from None


def _check_validity(cert: str) -> None:
    """MqttSetupError naming ``mqtt.tls.cert_file`` and its dates when the client certificate is not valid now; a
    warning logged when fewer than config.certificates.EXPIRY_WARNING_DAYS remain."""
    from cryptography import x509

    try:
        leaf = x509.load_pem_x509_certificate(Path(cert).read_bytes())  # the first certificate: the client's own
    except ValueError as err:
        raise MqttSetupError(f"mqtt.tls.cert_file: {cert} is not a PEM certificate ({err}); give the client "
                             "certificate the plant's CA issued, PEM") from None
    now = datetime.now(timezone.utc)
    problem, warning = certificate_dates(leaf, f"mqtt.tls.cert_file: {cert}", NEW_CLIENT_CERTIFICATE,
                                         refused="the broker refuses it", now=now)
    if problem is not None:
        raise (MqttCertificateNotValidYet if now < leaf.not_valid_before_utc else MqttSetupError)(problem)
    if warning is not None:
        log.warning("%s", warning)


class MqttPublication:
    """The outbox, bridge and publisher of one cell."""

    def __init__(self, config: MqttConfig, orchestrator: CellOrchestrator, *, workdir: Path) -> None:
        self.config = config
        self.workdir = workdir
        self.topics = CellTopics(config.isa95)
        self.outbox = Outbox(orchestrator.store, config.max_messages)
        machine = orchestrator.machine

        def state_now() -> tuple[str, str, str]:
            st = machine.status()
            return st.state.name, st.mode.name, st.cycle_step.name

        self.bridge = EventBridge(
            self.outbox, self.topics, orchestrator.events, state_now=state_now, alarms=orchestrator.alarms,
            calibration_now=orchestrator.calibration.reference,
        )  # fmt: skip
        self.publisher: MqttPublisher | None = None

    async def start(self) -> None:
        """Read the credentials, catch up the outbox, connect (in the background)."""
        password = read_password(self.config, self.workdir)
        tls = tls_parameters(self.config, self.workdir)
        await self.bridge.start()
        self.publisher = MqttPublisher(
            self.config, self.topics, self.outbox, password=password, tls=tls, caught_up=self.bridge.snapshot
        )
        self.publisher.start()

    async def stop(self) -> None:
        """Queue the last events, send what the grace allows, say offline, disconnect."""
        await self.bridge.stop()
        if self.publisher is not None:
            await self.publisher.stop(STOP_GRACE_S)

    def status(self) -> dict[str, Any]:
        """For /status (``mqtt``)."""
        if self.publisher is None:
            return {"broker": f"{self.config.host}:{self.config.port}", "connected": False, "started": False}
        return {"started": True, **self.publisher.status()}
