"""Shared test setup: the PLC emulator (tests/plc), the service harness (tests/service), the OPC UA client (tests/opcua) and
tests/shared_support.py are importable from every test folder."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
for folder in ("plc", "service", "opcua"):
    sys.path.insert(0, str(Path(__file__).parent / folder))


@pytest.fixture(autouse=True)
def _root_logging_restored() -> object:
    """A test that runs `cellctl ...` in-process configures the root logger (level, handler): undo it after,
    so a DEBUG level set by one test does not slow every later test (pymodbus and asyncua log each frame)."""
    root = logging.getLogger()
    level, handlers = root.level, list(root.handlers)
    yield
    for h in [h for h in root.handlers if h not in handlers]:
        root.removeHandler(h)
        h.close()
    root.setLevel(level)
