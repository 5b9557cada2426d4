"""The line PLC's Modbus TCP interface."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from cellctl.config.types import Finite, StrictModel


class PlcConfig(StrictModel):
    """Modbus TCP server settings."""

    enabled: bool = True
    host: str = "127.0.0.1"
    port: int = Field(5020, ge=1, le=65535)
    unit_id: int = Field(1, ge=0, le=255)
    float_word_order: Literal["big", "little"] = "big"  # "big": high word first (ABCD)
    heartbeat_timeout_s: Finite = Field(3.0, gt=0)
