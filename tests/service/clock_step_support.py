"""The wall clock seen by cellctl, stepped in-process as an NTP step (or a PC booted with a wrong date) steps it, with the
monotonic clock left alone: for the tests of certificates and calibrations dated by another clock than the one at start.

Every loaded cellctl module that did ``from datetime import datetime`` gets a datetime whose ``now()``/``utcnow()`` add
the offset (``isinstance`` still accepts real datetimes); ``time.time`` is shifted too, ``time.monotonic`` is not.

Run as a script, it is ``cellctl ARGS...`` with the wall clock stepped by ``$CELLCTL_TEST_CLOCK_OFFSET_S`` seconds.
"""

from __future__ import annotations

import importlib
import os
import sys
import time as _time
from datetime import datetime as _real
from datetime import timedelta, timezone, tzinfo

OFFSET = [timedelta(0)]
OFFSET_ENV = "CELLCTL_TEST_CLOCK_OFFSET_S"
_real_time = _time.time
# What reads the wall clock at start and in a cycle: imported before the patch, so that they are patched.
MODULES = ("cellctl.cli", "cellctl.service", "cellctl.service.compose", "cellctl.service.simulated", "cellctl.config.api",
           "cellctl.config.certificates", "cellctl.opcua.security", "cellctl.opcua.server", "cellctl.mqtt.publication",
           "cellctl.calibration.readiness", "cellctl.calibration.source", "cellctl.calibration.calibration_set",
           "cellctl.api.app")  # fmt: skip


class _Meta(type):
    def __instancecheck__(cls, obj: object) -> bool:
        return isinstance(obj, _real)

    def __subclasscheck__(cls, sub: type) -> bool:
        return issubclass(sub, _real)


class SteppedDatetime(_real, metaclass=_Meta):
    """datetime whose now() is the real one plus OFFSET."""

    @classmethod
    def now(cls, tz: tzinfo | None = None) -> _real:  # type: ignore[override]
        return _real.now(tz) + OFFSET[0]

    @classmethod
    def utcnow(cls) -> _real:  # type: ignore[override]
        return _real.utcnow() + OFFSET[0]


def _shifted_time() -> float:
    return _real_time() + OFFSET[0].total_seconds()


def install() -> None:
    """Patch every loaded cellctl module (MODULES are imported first)."""
    for name in MODULES:
        importlib.import_module(name)
    _time.time = _shifted_time
    for name, mod in list(sys.modules.items()):
        if mod is not None and name.startswith("cellctl") and getattr(mod, "datetime", None) is _real:
            mod.datetime = SteppedDatetime  # type: ignore[attr-defined]


def uninstall() -> None:
    """Undo :func:`install`: the real datetime in every module, the real ``time.time``, no offset."""
    _time.time = _real_time
    for mod in list(sys.modules.values()):
        if mod is not None and getattr(mod, "datetime", None) is SteppedDatetime:
            mod.datetime = _real  # type: ignore[attr-defined]
    reset()


def step(seconds: float) -> None:
    """A step of the wall clock by ``seconds`` (negative: back)."""
    OFFSET[0] += timedelta(seconds=seconds)


def reset() -> None:
    OFFSET[0] = timedelta(0)


def wall_now() -> _real:
    """The stepped wall clock, UTC."""
    return SteppedDatetime.now(timezone.utc)


if __name__ == "__main__":
    install()
    step(float(os.environ.get(OFFSET_ENV, "0")))
    from cellctl.cli import main

    sys.exit(main(sys.argv[1:]))
