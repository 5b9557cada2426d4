"""A CR-framed serial line on the asyncio event loop.

pyserial opens and configures the port (baud, 8N1, no flow control, exclusive lock); the loop
then watches the file descriptor with ``add_reader`` and reads it with ``os.read``. This is what
pyserial-asyncio does internally on POSIX, in a few lines and without the extra dependency: no
thread per port and no thread hop per exchange, which keeps the driver's CPU time per exchange
far below the wire time (see ``python -m keyence_lkg.bench``). A port that disappears (USB adapter
unplugged, pseudo-terminal closed) shows up as end of file or EIO on the descriptor and is
reported as :class:`LinkLost`; the reader is removed at once so a dead descriptor cannot spin
the loop.

POSIX only (the selector event loop); the cell controller runs on Linux.
"""

from __future__ import annotations

import asyncio
import collections
import math
import os
import termios
import time
from dataclasses import dataclass
from typing import Final

import serial

from keyence_lkg.codec import MAX_REPLY_CHARS

CR: Final = b"\r"
_READ_CHUNK: Final = 4096


@dataclass(frozen=True)
class ReconnectPolicy:
    """How a call reopens a port that vanished: up to ``attempts`` opens, ``interval_s`` apart."""

    attempts: int = 5
    interval_s: float = 0.5

    def __post_init__(self) -> None:
        if not isinstance(self.attempts, int) or self.attempts < 1:
            raise ValueError(f"reconnect attempts must be an integer >= 1, got {self.attempts!r}")
        if not (math.isfinite(self.interval_s) and self.interval_s > 0):
            raise ValueError(f"reconnect interval_s must be a positive number, got {self.interval_s!r}")


@dataclass
class LinkStats:
    """Counters for diagnostics (and for tests to see which recovery path ran)."""

    exchanges: int = 0
    timeouts: int = 0
    garbled_lines: int = 0
    late_replies: int = 0
    unsolicited_lines: int = 0
    resyncs: int = 0
    reconnects: int = 0
    mode_recoveries: int = 0


class LinkLost(Exception):
    """The port went away (unplugged adapter, closed pseudo-terminal) or cannot be opened."""


class LinkTimeout(Exception):
    """No complete line before the deadline."""


class SerialLine:
    """One open serial port, read as CR-terminated lines with their arrival times."""

    def __init__(self, port: str, baud: int) -> None:
        self.port = port
        self.baud = baud
        self._serial: serial.Serial | None = None
        self._fd: int = -1
        self._loop: asyncio.AbstractEventLoop | None = None
        self._buffer = bytearray()
        self._lines: collections.deque[tuple[bytes, float]] = collections.deque()
        self._waiter: asyncio.Future[None] | None = None
        self._lost: str | None = None
        self.bytes_written = 0
        self.bytes_read = 0
        self.write_started_s = math.nan  # time.monotonic() just before the last write's first byte went to the port
        self.max_line = MAX_REPLY_CHARS  # a longer run without CR is handed on as one (garbled) line

    @property
    def is_open(self) -> bool:
        """True while the port is open and has not been lost."""
        return self._serial is not None and self._lost is None

    def open(self) -> None:
        """Open the port (LinkLost if it cannot be opened) and start watching it."""
        self.close()
        try:
            ser = serial.Serial(
                self.port,
                self.baud,
                bytesize=serial.EIGHTBITS,
                parity=serial.PARITY_NONE,
                stopbits=serial.STOPBITS_ONE,
                timeout=0,
                write_timeout=0,
                xonxoff=False,
                rtscts=False,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError, termios.error) as exc:
            raise LinkLost(f"cannot open {self.port}: {exc}") from exc
        self._serial = ser
        self._fd = ser.fileno()
        os.set_blocking(self._fd, False)
        self._lost = None
        self._buffer.clear()
        self._lines.clear()
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(self._fd, self._on_readable)

    def close(self) -> None:
        """Stop watching and close the port; safe to call at any time."""
        if self._serial is None:
            return
        if self._loop is not None and self._fd >= 0:
            self._loop.remove_reader(self._fd)
        try:
            self._serial.close()
        except (serial.SerialException, OSError, termios.error):
            pass  # the device is already gone; the descriptor is released either way
        self._serial = None
        self._fd = -1
        self._wake()

    def flush_input(self) -> None:
        """Discard everything received and not yet read (kernel buffer, partial line, queued lines)."""
        self._buffer.clear()
        self._lines.clear()
        if self._serial is not None and self._lost is None:
            try:
                self._serial.reset_input_buffer()
            except (serial.SerialException, OSError, termios.error) as exc:
                self._mark_lost(f"flush failed: {exc}")

    async def write(self, data: bytes, deadline: float) -> None:
        """Send ``data`` completely before ``deadline`` (loop time); LinkLost / LinkTimeout otherwise."""
        self._check_usable()
        view = memoryview(data)
        self.write_started_s = time.monotonic()  # nothing of it can have reached the device before this
        while view:
            try:
                n = os.write(self._fd, view)
            except BlockingIOError:
                n = 0
            except OSError as exc:
                self._mark_lost(f"write failed: {exc}")
                self._check_usable()
                return
            self.bytes_written += n
            view = view[n:]
            if view:
                await self._wait_writable(deadline)

    async def read_line(self, deadline: float) -> tuple[bytes, float]:
        """The next line (without CR) and its arrival time (time.monotonic())."""
        while True:
            if self._lines:
                return self._lines.popleft()
            self._check_usable()
            loop = asyncio.get_running_loop()
            if loop.time() >= deadline:
                raise LinkTimeout("no complete line before the deadline")
            waiter = loop.create_future()
            self._waiter = waiter
            handle = loop.call_at(deadline, self._expire, waiter)
            try:
                await waiter
            finally:
                handle.cancel()
                self._waiter = None

    # internals ---------------------------------------------------------------------------------

    def _check_usable(self) -> None:
        if self._lost is not None:
            raise LinkLost(f"{self.port}: {self._lost}")
        if self._serial is None:
            raise LinkLost(f"{self.port} is not open")

    def _on_readable(self) -> None:
        try:
            data = os.read(self._fd, _READ_CHUNK)
        except BlockingIOError:
            return
        except OSError as exc:
            self._mark_lost(f"read failed: {exc}")
            return
        if not data:
            self._mark_lost("end of file (device disconnected)")
            return
        now = time.monotonic()
        self.bytes_read += len(data)
        buf = self._buffer
        buf += data
        while True:
            i = buf.find(CR)
            if i < 0:
                break
            self._lines.append((bytes(buf[:i]), now))
            del buf[: i + 1]
        if len(buf) > self.max_line:
            # a run of bytes without CR: hand it on as one (garbled) line so it is seen and dropped
            self._lines.append((bytes(buf), now))
            buf.clear()
        if self._lines:
            self._wake()

    def _mark_lost(self, why: str) -> None:
        if self._lost is None:
            self._lost = why
        if self._loop is not None and self._fd >= 0:
            self._loop.remove_reader(self._fd)
        self._wake()

    def _wake(self) -> None:
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    @staticmethod
    def _expire(waiter: asyncio.Future[None]) -> None:
        if not waiter.done():
            waiter.set_result(None)

    async def _wait_writable(self, deadline: float) -> None:
        loop = asyncio.get_running_loop()
        if loop.time() >= deadline:
            raise LinkTimeout("port not writable before the deadline")
        fut: asyncio.Future[None] = loop.create_future()
        loop.add_writer(self._fd, self._expire, fut)
        handle = loop.call_at(deadline, self._expire, fut)
        try:
            await fut
        finally:
            handle.cancel()
            loop.remove_writer(self._fd)
