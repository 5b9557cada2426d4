"""Read a TOML file into :class:`CellConfig`; any problem becomes one readable ConfigError."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from cellctl.config.schema import CellConfig


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
    """Validate an already parsed TOML document."""
    try:
        return CellConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(format_validation_errors(source, err)) from None


def load_config(path: str | Path) -> CellConfig:
    """Load and validate a TOML configuration file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: configuration file not found (the default is config/sim.toml)") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{p}: not valid TOML: {err}") from None
    return parse_config(data, str(p))
