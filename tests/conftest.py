"""Shared test setup: the PLC emulator (tests/plc), the service harness (tests/service) and
tests/shared_support.py are importable from every test folder."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
for folder in ("plc", "service"):
    sys.path.insert(0, str(Path(__file__).parent / folder))
