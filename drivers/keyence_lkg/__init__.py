"""Keyence LK-G laser displacement sensor (LK-G3001 and LK-G5001 controllers) over RS-232C.

- :class:`KeyenceLkgSensor`: the asyncio driver, a :class:`cellctl.ports.DisplacementSensor` and,
  by the controller's data storage (``storage``), a :class:`cellctl.ports.StoringSensor`.
- :class:`FakeLkgController`: a simulated controller on a pseudo-terminal, for tests and the
  simulated cell (its storage in ``fake_storage``).
- ``codec``, ``units``, ``errors``: the protocol of both dialects.
- ``python -m keyence_lkg.bench``: the driver's CPU time per exchange against the wire time.
"""

from keyence_lkg.codec import Command, ErrorReply, GarbledReply, LkgDialect, Reply, dialect_for
from keyence_lkg.driver import KeyenceLkgSensor
from keyence_lkg.errors import DIALECTS, ERROR_CODES, Dialect, describe_error
from keyence_lkg.fake import FakeExchange, FakeLkgController
from keyence_lkg.link import LinkStats, ReconnectPolicy
from keyence_lkg.units import DISPLAY_UNITS, DisplayUnit, ValueKind, WireValue

__all__ = [
    "DIALECTS",
    "DISPLAY_UNITS",
    "ERROR_CODES",
    "Command",
    "Dialect",
    "DisplayUnit",
    "ErrorReply",
    "FakeExchange",
    "FakeLkgController",
    "GarbledReply",
    "KeyenceLkgSensor",
    "LinkStats",
    "LkgDialect",
    "ReconnectPolicy",
    "Reply",
    "ValueKind",
    "WireValue",
    "describe_error",
    "dialect_for",
]
