"""A plain-text progress display for long benchmark runs (no dependency).

On a terminal it redraws one line (bar, count, rate, time left, a note); otherwise it prints a
line at every tenth of the run, so logs stay short. It writes to stderr, so a report on stdout
stays clean.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

BAR_WIDTH = 28


class Progress:
    """Progress of ``total`` steps of one task.

    Args:
        label: what is being done ("accuracy trials").
        total: number of steps (at least 1).
        stream: where to draw (default stderr).
        enabled: False draws nothing (tests, --quiet).
    """

    def __init__(self, label: str, total: int, *, stream: TextIO | None = None, enabled: bool = True) -> None:
        if total < 1:
            raise ValueError(f"progress total must be at least 1, got {total}")
        self.label = label
        self.total = int(total)
        self.done = 0
        self._stream = stream if stream is not None else sys.stderr
        self._enabled = enabled
        self._tty = bool(getattr(self._stream, "isatty", lambda: False)())
        self._t0 = time.monotonic()
        self._next_line = 0

    def advance(self, note: str = "", steps: int = 1) -> None:
        """``steps`` more are done; ``note`` says something about the latest (e.g. its outcome)."""
        self.done = min(self.total, self.done + steps)
        if not self._enabled:
            return
        elapsed = time.monotonic() - self._t0
        rate = self.done / elapsed if elapsed > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("nan")
        if self._tty:
            filled = int(BAR_WIDTH * self.done / self.total)
            bar = "#" * filled + "-" * (BAR_WIDTH - filled)
            eta = f"{left:5.0f} s left" if left == left else "       "
            line = f"\r{self.label} [{bar}] {self.done}/{self.total} {rate:5.2f}/s {eta} {note}"
            self._stream.write(line[:160].ljust(100))
            if self.done == self.total:
                self._stream.write("\n")
            self._stream.flush()
        elif self.done >= self._next_line or self.done == self.total:
            self._stream.write(f"{self.label}: {self.done}/{self.total} after {elapsed:.0f} s {note}\n")
            self._stream.flush()
            self._next_line = self.done + max(1, self.total // 10)

    def message(self, text: str) -> None:
        """A line of its own (a phase starting, a warning), not overwritten by the bar."""
        if not self._enabled:
            return
        if self._tty:
            self._stream.write("\r" + " " * 100 + "\r")
        self._stream.write(text + "\n")
        self._stream.flush()
