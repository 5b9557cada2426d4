"""The process's log: level, plain text or JSON lines, and repeats collapsed.

``configure_logging`` is called once by ``cellctl`` (``--log-level``, ``--log-format``); it puts one
handler on the root logger, so the drivers' loggers (``abb_robot.client``, ``keyence_lkg``, ...)
and uvicorn's come out the same way. The handler carries a :class:`RepeatFilter`: a message
repeated while a device is away (``robot: link down: ...`` at every reconnection attempt) is
logged the first time, then at most once per window with how often it came meanwhile.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections.abc import Callable
from datetime import datetime, timezone
from typing import TextIO

LEVELS = ("debug", "info", "warning", "error", "critical")
FORMATS = ("text", "json")
LEVEL_ENV = "CELLCTL_LOG_LEVEL"
FORMAT_ENV = "CELLCTL_LOG_FORMAT"
TEXT_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
REPEAT_WINDOW_S = 60.0
CHATTY_LOGGERS = ("asyncua",)
"""Libraries that log at info what only debugging needs (asyncua: ~1,400 address-space lines at each OPC UA start):
capped at warning unless the level is debug. pymodbus logs one line at start and is left alone."""


class JsonFormatter(logging.Formatter):
    """One JSON object per line: ``ts`` (UTC, ISO 8601), ``level``, ``logger``, ``message``, and
    ``exc_info`` (the formatted traceback) and ``stack_info`` when the record has them."""

    def format(self, record: logging.LogRecord) -> str:
        doc: dict[str, object] = {
            "ts": datetime.fromtimestamp(record.created, timezone.utc).isoformat(timespec="milliseconds"),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        if record.exc_info:
            doc["exc_info"] = self.formatException(record.exc_info)
        elif record.exc_text:
            doc["exc_info"] = record.exc_text
        if record.stack_info:
            doc["stack_info"] = self.formatStack(record.stack_info)
        return json.dumps(doc, ensure_ascii=False, default=str)


class RepeatFilter(logging.Filter):
    """Lets a message through once per ``window_s``: the first time it comes, then the first time after
    the window, with `` (repeated N times in the last S s)`` appended for the ones held back.

    A message is the same when its logger, level and text are (``record.getMessage()``).
    """

    def __init__(self, window_s: float = REPEAT_WINDOW_S, clock: Callable[[], float] = time.monotonic,
                 max_keys: int = 1000) -> None:  # fmt: skip
        super().__init__()
        self.window_s = window_s
        self._clock = clock
        self._max_keys = max_keys
        self._seen: dict[tuple[str, int, str], list[float | int]] = {}  # key -> [last let through, held back since]

    def filter(self, record: logging.LogRecord) -> bool:
        now = self._clock()
        text = record.getMessage()
        key = (record.name, record.levelno, text)
        seen = self._seen.get(key)
        if seen is not None and now - seen[0] < self.window_s:
            seen[1] += 1
            return False
        if seen is not None and seen[1]:
            n = int(seen[1])
            record.msg = f"{text} (repeated {n} time{'s' if n != 1 else ''} in the last {now - seen[0]:.0f} s)"
            record.args = None
        if len(self._seen) >= self._max_keys:
            self._forget(now)
        self._seen[key] = [now, 0]
        return True

    def _forget(self, now: float) -> None:
        """Drop the messages whose window has passed (bounded memory under many distinct messages)."""
        for key in [k for k, (at, _) in self._seen.items() if now - at >= self.window_s]:
            del self._seen[key]
        while len(self._seen) >= self._max_keys:  # all recent: the one let through longest ago goes
            del self._seen[min(self._seen, key=lambda k: self._seen[k][0])]


class _StderrHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """Writes to whatever ``sys.stderr`` is at the time (as :data:`logging.lastResort` does), not the one it was made with."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property  # type: ignore[override]
    def stream(self) -> TextIO:
        return sys.stderr

    @stream.setter
    def stream(self, value: TextIO) -> None:
        pass


def level_from(text: str | None) -> int:
    """A level name (``debug`` ... ``critical``, any case) as its number; ValueError names the choices."""
    name = (text or "warning").strip().lower()
    if name not in LEVELS:
        raise ValueError(f"unknown log level {text!r}; choose one of {', '.join(LEVELS)}")
    return int(getattr(logging, name.upper()))


def configure_logging(level: str | None = None, fmt: str | None = None, *, stream: TextIO | None = None,
                      window_s: float = REPEAT_WINDOW_S) -> logging.Handler:  # fmt: skip
    """Route every logger to one handler on ``stream`` (stderr): ``level`` (else $CELLCTL_LOG_LEVEL, else
    warning), ``fmt`` ``text`` or ``json`` (else $CELLCTL_LOG_FORMAT, else text); repeats collapsed; the
    :data:`CHATTY_LOGGERS` at warning unless ``level`` is debug.

    Replaces the handlers a previous call installed, so it may be called again (tests do)."""
    lvl = level_from(level or os.environ.get(LEVEL_ENV))
    form = (fmt or os.environ.get(FORMAT_ENV) or "text").strip().lower()
    if form not in FORMATS:
        raise ValueError(f"unknown log format {form!r}; choose one of {', '.join(FORMATS)}")
    handler: logging.Handler = logging.StreamHandler(stream) if stream is not None else _StderrHandler()
    handler.setFormatter(JsonFormatter() if form == "json" else logging.Formatter(TEXT_FORMAT))
    handler.addFilter(RepeatFilter(window_s))
    handler._cellctl = True  # type: ignore[attr-defined]  # ours, replaced by the next call
    root = logging.getLogger()
    for old in [h for h in root.handlers if getattr(h, "_cellctl", False)]:
        root.removeHandler(old)
        old.close()
    root.addHandler(handler)
    root.setLevel(lvl)
    for name in CHATTY_LOGGERS:
        logging.getLogger(name).setLevel(logging.NOTSET if lvl <= logging.DEBUG else logging.WARNING)
    return handler
