"""Shared test setup: the PLC emulator (tests/plc) and the service harness (tests/service) are
importable from every test folder."""

from __future__ import annotations

import sys
from pathlib import Path

for folder in ("plc", "service"):
    sys.path.insert(0, str(Path(__file__).parent / folder))
