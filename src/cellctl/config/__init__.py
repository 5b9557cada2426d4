"""The cell's configuration: one pydantic schema, loaded from TOML, refused with a clear message."""

from cellctl.config.loader import ConfigError, load_config, parse_config
from cellctl.config.schema import CellConfig

__all__ = ["CellConfig", "ConfigError", "load_config", "parse_config"]
