"""Publication to the plant's MQTT broker ([mqtt]; optional, off by default).

The cell publishes its state, every finished cycle's result, its alarms and its calibration
version under an ISA-95 topic tree (``{enterprise}/{site}/{area}/{line}/{cell}/cellctl/...``),
QoS 1, through a durable bounded outbox (docs/mqtt.md). A password is never written here: name a
file (``password_file``) that holds it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from cellctl.config.types import Finite, StrictModel

ISA95_LEVELS: tuple[str, ...] = ("enterprise", "site", "area", "line", "cell")
"""The ISA-95 equipment hierarchy, top down: the first five levels of every topic."""

MAX_LEVEL_LENGTH = 64


def level_problem(value: str) -> str | None:
    """Why ``value`` cannot be one level of an MQTT topic (None: it can)."""
    if not value:
        return "is empty"
    if len(value) > MAX_LEVEL_LENGTH:
        return f"has {len(value)} characters, more than {MAX_LEVEL_LENGTH}"
    bad = sorted({c for c in value if c in "+#/"})
    if bad:
        return f"contains {' '.join(repr(c) for c in bad)}: '+' and '#' are MQTT wildcards and '/' separates levels"
    if value.startswith("$"):
        return "starts with '$', which brokers reserve for their own topics ($SYS)"
    if value != value.strip() or any(not c.isprintable() for c in value):
        return "has leading or trailing white space or control characters"
    return None


class Isa95Names(StrictModel):
    """The cell's place in the plant: one topic level each (letters, digits, '-', '_', '.' are safe)."""

    enterprise: str = "enterprise"
    site: str = "site"
    area: str = "area"
    line: str = "line"
    cell: str = "cell-1"

    @field_validator(*ISA95_LEVELS)
    @classmethod
    def _one_level(cls, v: str) -> str:
        why = level_problem(v)
        if why is not None:
            raise ValueError(f"the topic level {v!r} {why}; use e.g. letters, digits, '-' and '_'")
        return v

    def levels(self) -> tuple[str, ...]:
        return tuple(getattr(self, name) for name in ISA95_LEVELS)


class MqttTls(StrictModel):
    """TLS to the broker: the CA that signed the broker's certificate, and optionally a client certificate."""

    ca_file: Path
    cert_file: Path | None = None
    key_file: Path | None = None

    @model_validator(mode="after")
    def _pair(self) -> MqttTls:
        if (self.cert_file is None) != (self.key_file is None):
            raise ValueError("a client certificate needs both cert_file and key_file (or neither, for server-only TLS)")
        return self


class MqttConfig(StrictModel):
    """The broker, the cell's topic tree, reconnection and the outbox's bound (docs/mqtt.md)."""

    enabled: bool = False
    host: str = Field("127.0.0.1", min_length=1)
    port: int = Field(1883, ge=1, le=65535)
    client_id: str | None = Field(None, min_length=1, max_length=64)  # default: cellctl-<isa95.cell>
    username: str | None = Field(None, min_length=1)
    password_file: Path | None = None  # the password on one line (chmod 600); relative to the work directory
    tls: MqttTls | None = None
    keepalive_s: int = Field(30, ge=5, le=3600)  # the broker publishes the will after 1.5 x this without a word
    qos: Literal[1] = 1  # at least once: results are never published with QoS 0
    isa95: Isa95Names = Isa95Names()
    reconnect_min_s: Finite = Field(0.5, gt=0, le=60)  # back-off after a failed connection, doubled each time ...
    reconnect_max_s: Finite = Field(30.0, gt=0, le=600)  # ... up to this (with random jitter)
    max_messages: int = Field(10_000, ge=10, le=1_000_000)  # outbox bound; beyond it the oldest go (results last)
    publish_timeout_s: Finite = Field(10.0, gt=0, le=300)  # longest wait for a PUBACK, a CONNACK or a disconnect

    @model_validator(mode="before")
    @classmethod
    def _no_inline_password(cls, data: Any) -> Any:
        if isinstance(data, dict) and "password" in data:
            raise ValueError(
                "mqtt.password: a password is never written in the configuration; put it in a file "
                "(one line, chmod 600) and give its path as mqtt.password_file"
            )
        return data

    @model_validator(mode="after")
    def _consistent(self) -> MqttConfig:
        if self.reconnect_max_s < self.reconnect_min_s:
            raise ValueError(
                f"mqtt.reconnect_max_s = {self.reconnect_max_s:g} s is below mqtt.reconnect_min_s = "
                f"{self.reconnect_min_s:g} s: raise the maximum or lower the minimum"
            )
        if self.password_file is not None and self.username is None:
            raise ValueError("mqtt.password_file is set but mqtt.username is not: give the user name the password belongs to")
        return self

    def hardware_problems(self) -> list[str]:
        """What a hardware cell refuses in this section: a broker password sent without TLS (field: message)."""
        if self.enabled and self.password_file is not None and self.tls is None:
            return [(
                f"mqtt.tls: mqtt.username '{self.username}' logs in with mqtt.password_file but [mqtt.tls] is not set, "
                "so the password would cross the plant network in clear; add [mqtt.tls] with ca_file (the CA of the "
                "broker's certificate) and the broker's TLS port (usually 8883), or remove password_file"
            )]
        return []

    @property
    def effective_client_id(self) -> str:
        """The MQTT client id: ``client_id``, else ``cellctl-<isa95.cell>``."""
        return self.client_id or f"cellctl-{self.isa95.cell}"
