"""Read a TOML file into :class:`CellConfig`; any problem becomes one readable ConfigError."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from cellctl.config.api import TokenUnavailable
from cellctl.config.schema import CellConfig

MAX_CONFIG_BYTES = 4 * 1024**2  # a cell's configuration is a few kB


class ConfigError(ValueError):
    """The configuration cannot be used. The message names each bad field and what to do."""


def format_validation_errors(
    source: str,
    err: ValidationError,
    *,
    what: str = "the configuration",
    unknown_field: str = "unknown field; check its spelling against config/sim.toml",
) -> str:
    """One readable message naming every bad field of a pydantic validation error."""
    lines = [f"{source}: {err.error_count()} problem(s) in {what}:"]
    for e in err.errors():
        where = ".".join(str(p) for p in e["loc"] if not str(p).startswith("function-after")) or "(top level)"
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg = unknown_field
        elif e["type"] == "missing":
            msg = "required field is missing"
        lines.append(f"  - {where}: {msg}")
    return "\n".join(lines)


def parse_config(data: dict[str, Any], source: str = "<config>") -> CellConfig:
    """Validate an already parsed TOML document (what its mode demands of the other sections included)."""
    try:
        config = CellConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(format_validation_errors(source, err)) from None
    return config


def check_tokens(config: CellConfig, source: str = "<config>") -> None:
    """Read every API token now (environment variable, file) and check it; any that cannot be used is a ConfigError.

    ``cellctl serve`` calls this before it builds anything: a service must not start with a token it
    cannot read. Commands that only talk to a running service do not need the service's tokens.
    """
    problems: list[str] = []
    try:
        config.api.secrets()
    except TokenUnavailable as err:
        problems += str(err).splitlines()
    if config.opcua.enabled:
        for user in config.opcua.users:
            if user.certificate is None:
                try:
                    user.secret()
                except TokenUnavailable as err:
                    problems.append(str(err))
    if problems:
        lines = [f"{source}: {len(problems)} API token(s) or OPC UA password(s) cannot be used:", *(f"  - {p}" for p in problems)]
        raise ConfigError("\n".join(lines)) from None


def load_config(path: str | Path, *, read_tokens: bool = False) -> CellConfig:
    """Load and validate a TOML configuration file; ``read_tokens``: also :func:`check_tokens` (for the service)."""
    p = Path(path)
    hint = "give the path of a TOML file (without --config: $CELLCTL_CONFIG, else the simulated cell's configuration)"
    try:
        if p.is_dir():
            raise IsADirectoryError
        if p.exists() and not p.is_file():
            raise ConfigError(f"{p}: not a regular file (a device or a pipe?); {hint}")
        with p.open("rb") as f:
            raw = f.read(MAX_CONFIG_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"{p}: configuration file not found; {hint}") from None
    except IsADirectoryError:
        raise ConfigError(f"{p}: is a directory, not a configuration file; {hint}") from None
    except OSError as err:
        raise ConfigError(f"{p}: the configuration file cannot be read ({err.strerror or err}); {hint}") from None
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{p}: larger than {MAX_CONFIG_BYTES // 1024**2} MiB, not a cell configuration; {hint}")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw[: err.start].count(b"\n") + 1
        raise ConfigError(
            f"{p}: not UTF-8 text (byte 0x{raw[err.start]:02x} on line {line}); TOML files are UTF-8: "
            "save it as UTF-8, or give the right file"
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{p}: not valid TOML: {err}") from None
    config = parse_config(data, str(p))
    if read_tokens:
        check_tokens(config, str(p))
    return config
