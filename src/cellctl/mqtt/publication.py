"""MQTT publication of one cell, put together: outbox, bridge and publisher around the orchestrator.

The service builds it when ``[mqtt] enabled`` (:mod:`cellctl.service.compose`), starts it after
the orchestrator (its catch-up reads the recovered store) and stops it before the store closes.
Credentials and TLS files are read at :meth:`MqttPublication.start`; one that cannot be used
raises :class:`MqttSetupError` naming the field.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import aiomqtt

from cellctl.config.api import TokenUnavailable, open_to_everyone, read_secret
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


class MqttSetupError(ValueError):
    """A credential or TLS file named in [mqtt] cannot be used; the message names the field and the fix."""


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
    """aiomqtt's TLS settings from ``mqtt.tls``, every file checked to be readable now, the client's key to be
    readable by the service only (as the password file)."""
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
    return aiomqtt.TLSParameters(ca_certs=files["ca_file"], certfile=files["cert_file"], keyfile=files["key_file"])


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
