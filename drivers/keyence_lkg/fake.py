"""A simulated LK-G controller speaking the RS-232C protocol on a pseudo-terminal.

The fake owns a pseudo-terminal pair and a symbolic link at a path it controls; the driver opens
that path exactly as it would ``/dev/ttyUSB0``. It answers in order, one reply per command, in
the chosen dialect (LK-G3001 or LK-G5001), keeps the mode rules (measuring in general mode,
settings in communication mode) and answers rule breaks with that dialect's error codes. Its data
storage (``AQ``/``AS``/``AP``/``AN``/``AO``) is keyence_lkg.fake_storage, sampled on the serving thread.

Physics comes from a callback per OUT: ``distance() -> float | None | LaserStatus``, the distance
along the laser from its origin r in mm (the twin's ray cast), ``None`` for no return (shown as
far over range), or a :class:`LaserStatus` to force that status. The fake turns it into the
displacement the controller shows: ``sign * (distance - reference_distance_mm)`` plus the OUT's
offset setting, in the display unit, over range beyond ``measuring_range_mm`` or beyond what
seven characters can show.

Faults for tests: :meth:`silence` (commands lost), :meth:`garble` (noise before, instead of or
cutting a reply), :meth:`delay` (slow replies), :meth:`inject_error` (an ``ER`` with any code, e.g.
88/99), :meth:`send_unsolicited` (a line nobody asked for), :meth:`vanish` / :meth:`reappear`
(the USB adapter unplugged and plugged back: the pseudo-terminal is closed, the link removed,
then a new one is made at the same path).

Choices the manual does not settle (kept in one place, see DESIGN notes B1-B4): an empty line
or a lone LF is ignored; a main command that is not two characters gets the length error; the
mode is checked before the parameters; an unknown setting identifier gets the parameter error;
an LK-G5001 OUT beyond ``out_count`` reads ``XXXXXXXX``; a callback that raises gets ``99``.
"""

from __future__ import annotations

import collections
import logging
import os
import random
import select
import tempfile
import threading
import time
import tty
from dataclasses import dataclass
from typing import Callable, Literal, Mapping

from keyence_lkg.errors import DIALECTS, ERROR_CODES, Dialect
from keyence_lkg.fake_commands import MAX_COMMAND_CHARS, DistanceSource, LkgCommandSet, Mode, setting_specs
from keyence_lkg.fake_storage import StorageState
from keyence_lkg.units import unit_format

_log = logging.getLogger(__name__)

GarbleKind = Literal["noise_line", "prefix", "replace", "truncate"]


@dataclass(frozen=True)
class FakeExchange:
    """One command the fake received and what it sent back (None: no reply)."""

    command: str
    reply: str | None
    values_mm: tuple[float | None, ...] = ()  # the displayed value(s) in mm, for measurement replies


class FakeLkgController(LkgCommandSet):
    """The simulated controller. Use as a context manager, or call :meth:`start` / :meth:`stop`.

    Args:
        dialect: "LK-G3001" or "LK-G5001".
        distance: the distance source of OUT1, or a mapping OUT -> source (others read XXXXXXXX).
        link_path: where the symbolic link to the pseudo-terminal goes (default: a new temp dir).
        display_unit: the minimum display unit the fake formats values in.
        reference_distance_mm: distance along the laser that reads 0.
        measuring_range_mm: half span around the reference distance (LK-G500 in the twin: 100).
        displacement_positive: which way a positive displacement points.
        out_count: OUTs in use (MA answers this many); LK-G3001 always has 2.
        seed: for the garbage bytes.
        keep_exchanges: how many recent exchanges :attr:`exchanges` keeps (for tests and diagnostics).
    """

    def __init__(
        self,
        dialect: str,
        distance: DistanceSource | Mapping[int, DistanceSource],
        *,
        link_path: str | None = None,
        display_unit: str = "0.001mm",
        reference_distance_mm: float = 350.0,
        measuring_range_mm: float = 100.0,
        displacement_positive: Literal["away_from_head", "toward_head"] = "away_from_head",
        out_count: int | None = None,
        seed: int = 0,
        keep_exchanges: int = 10_000,
    ) -> None:
        if dialect not in DIALECTS:
            raise ValueError(f"dialect must be one of {DIALECTS}, got {dialect!r}")
        self.dialect: Dialect = dialect  # type: ignore[assignment]
        self.setting_errors_name_the_setting = False  # True: ER,<setting id>,xx for SW/SR, as the ISIS emulator
        self._sources: dict[int, DistanceSource] = dict(distance) if isinstance(distance, Mapping) else {1: distance}
        max_out = 2 if dialect == "LK-G3001" else 12
        if dialect == "LK-G3001":
            out_count = 2
        elif out_count is None:
            out_count = max(self._sources, default=1)
        if not 1 <= out_count <= max_out or any(not 1 <= o <= out_count for o in self._sources):
            raise ValueError(f"OUT numbers must lie in 1..out_count ({out_count}) and out_count in 1..{max_out}")
        self.out_count = out_count
        self.unit = unit_format(display_unit)
        self.reference_distance_mm = float(reference_distance_mm)
        self.measuring_range_mm = float(measuring_range_mm)
        self._sign = 1.0 if displacement_positive == "away_from_head" else -1.0
        self._own_dir: str | None = None
        if link_path is None:
            self._own_dir = tempfile.mkdtemp(prefix="fake-lkg-")
            link_path = os.path.join(self._own_dir, "ttyLKG0")
        self.path = link_path
        self.mode: Mode = "general"
        self.storage = StorageState()
        self._specs = setting_specs(self.dialect)
        self._settings: dict[tuple[str, tuple[str, ...]], tuple[str, ...]] = {}
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._requests: list[Callable[[], None]] = []
        self._master: int | None = None
        self._slave: int | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._inbuf = bytearray()
        # faults
        self._silent: int | None = 0  # commands to ignore; None = all
        self._garble: list[GarbleKind] = []
        self._garble_forever: GarbleKind | None = None
        self._delay_s = 0.0
        self._delays: list[float] = []
        self._errors: list[str] = []
        self.exchanges: collections.deque[FakeExchange] = collections.deque(maxlen=keep_exchanges)

    # ------------------------------------------------------------------------------------------
    # life cycle

    def start(self) -> "FakeLkgController":
        """Create the pseudo-terminal and link, and start answering."""
        if self._thread is not None:
            return self
        self._open_pty()
        self._thread = threading.Thread(target=self._serve, name=f"fake {self.dialect}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop answering and remove the pseudo-terminal and link."""
        self._stop.set()
        self._poke()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        self._close_pty()
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass
        self._wake_r = self._wake_w = -1
        if self._own_dir is not None:
            try:
                os.rmdir(self._own_dir)
            except OSError:
                pass

    def __enter__(self) -> "FakeLkgController":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def pty_path(self) -> str | None:
        """The current /dev/pts/N behind the link (changes after vanish/reappear)."""
        with self._lock:
            return os.ttyname(self._slave) if self._slave is not None else None

    # ------------------------------------------------------------------------------------------
    # faults (thread-safe; they apply to the next commands)

    def silence(self, count: int | None = 1) -> None:
        """Ignore the next ``count`` commands (None: all, until :meth:`speak`), as if lost on the wire."""
        with self._lock:
            self._silent = count

    def speak(self) -> None:
        """Answer again after :meth:`silence`."""
        with self._lock:
            self._silent = 0

    def garble(self, kind: GarbleKind = "replace", count: int | None = 1) -> None:
        """Spoil the next ``count`` replies (None: all, until :meth:`clear_faults`).

        noise_line: a line of noise before the reply; prefix: noise glued to the front of the
        reply; replace: noise instead of the reply; truncate: only the first half of the reply, no CR.
        """
        with self._lock:
            if count is None:
                self._garble_forever = kind
            else:
                self._garble.extend([kind] * count)

    def delay(self, seconds: float, count: int | None = 1) -> None:
        """Delay the next ``count`` replies by ``seconds`` (None: every reply from now on)."""
        with self._lock:
            if count is None:
                self._delay_s = seconds
            else:
                self._delays.extend([seconds] * count)

    def inject_error(self, code: str, count: int = 1) -> None:
        """Answer the next ``count`` commands with ``ER,<main>,<code>`` (any code, e.g. 88 or 99)."""
        if code not in ERROR_CODES[self.dialect]:
            raise ValueError(f"{code!r} is not an {self.dialect} error code")
        with self._lock:
            self._errors.extend([code] * count)

    def clear_faults(self) -> None:
        """Back to a healthy controller (the mode and settings stay)."""
        with self._lock:
            self._silent = 0
            self._garble.clear()
            self._garble_forever = None
            self._delay_s = 0.0
            self._delays.clear()
            self._errors.clear()

    def send_unsolicited(self, line: str) -> None:
        """Push a line nobody asked for (e.g. a ``TG,`` timing frame)."""
        self._request(lambda: self._write(line.encode("ascii") + b"\r"))

    def set_source(self, out: int, source: DistanceSource) -> None:
        """Swap the distance source of one OUT while the fake runs (e.g. to plug in the twin's ray cast)."""
        if not 1 <= out <= self.out_count:
            raise ValueError(f"OUT {out} is not in 1..{self.out_count}")
        with self._lock:
            self._sources[out] = source

    def set_mode(self, mode: Mode) -> None:
        """Put the controller in a mode directly (e.g. left in communication mode by another tool)."""
        with self._lock:
            self.mode = mode

    def vanish(self) -> None:
        """The USB adapter is unplugged: close the pseudo-terminal and remove the link."""
        self._request(self._close_pty)

    def reappear(self) -> None:
        """The adapter is back: a new pseudo-terminal behind a link at the same path."""
        self._request(self._open_pty)

    # ------------------------------------------------------------------------------------------
    # pseudo-terminal

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no CR/LF translation, whoever opens it
        os.set_blocking(master, False)
        with self._lock:
            self._master, self._slave = master, slave
        self._inbuf.clear()
        tmp = f"{self.path}.{os.getpid()}.tmp"
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.path)

    def _close_pty(self) -> None:
        try:
            os.unlink(self.path)
        except FileNotFoundError:
            pass
        with self._lock:
            fds = (self._master, self._slave)
            self._master = self._slave = None
        for fd in fds:
            if fd is not None:
                os.close(fd)

    def _request(self, action: Callable[[], None], timeout_s: float = 5.0) -> None:
        """Run ``action`` on the fake's thread (it owns the descriptors) and wait until it ran."""
        if self._thread is None:
            action()
            return
        done = threading.Event()

        def run() -> None:
            try:
                action()
            finally:
                done.set()

        with self._lock:
            self._requests.append(run)
        self._poke()
        if not done.wait(timeout_s):
            raise TimeoutError("the fake controller's thread did not run the request")

    def _poke(self) -> None:
        try:
            os.write(self._wake_w, b"!")
        except (OSError, ValueError):
            pass

    # ------------------------------------------------------------------------------------------
    # the serving thread

    def _serve(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                master = self._master
                requests, self._requests = self._requests, []
            for run in requests:
                run()
            if requests:
                continue
            watch = [self._wake_r] + ([master] if master is not None else [])
            due = self.storage.next_due_s(time.monotonic())
            try:
                ready, _, _ = select.select(watch, [], [], 0.5 if due is None else min(0.5, due))
            except (OSError, ValueError):
                continue
            self.sample_storage(time.monotonic())
            if self._wake_r in ready:
                try:
                    os.read(self._wake_r, 4096)
                except BlockingIOError:
                    pass
            if master is not None and master in ready:
                try:
                    data = os.read(master, 4096)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError:
                    continue  # nobody has the other end open; wait for requests
                self._receive(data)

    def _receive(self, data: bytes) -> None:
        self._inbuf += data.replace(b"\n", b"")  # a stray LF is ignored
        while True:
            i = self._inbuf.find(b"\r")
            if i < 0:
                if len(self._inbuf) > 4 * MAX_COMMAND_CHARS:
                    self._inbuf.clear()  # noise without CR: the controller would drop it
                return
            raw = bytes(self._inbuf[:i])
            del self._inbuf[: i + 1]
            if raw:
                self._answer(raw.decode("latin-1"))

    def _answer(self, text: str) -> None:
        with self._lock:
            lost = self._silent is None or self._silent > 0
            if self._silent:
                self._silent -= 1
            forced = self._errors.pop(0) if self._errors and not lost else None
        if lost:
            self._log(FakeExchange(text, None))
            return
        values: tuple[float | None, ...] = ()
        if forced is not None:
            reply = f"ER,{self._main_of(text)},{forced}"
        else:
            reply, values = self._handle(text)
        with self._lock:
            wait = self._delay_s + (self._delays.pop(0) if self._delays else 0.0)
            kind = self._garble.pop(0) if self._garble else self._garble_forever
        self._log(FakeExchange(text, reply, values))
        if wait > 0:
            self._stop.wait(wait)
        self._write(self._spoil(reply.encode("ascii") + b"\r", kind))

    def _spoil(self, wire: bytes, kind: GarbleKind | None) -> bytes:
        if kind is None:
            return wire
        noise = bytes(self._rng.choice([b for b in range(256) if b != 0x0D]) for _ in range(12))
        if kind == "noise_line":
            return noise + b"\r" + wire
        if kind == "prefix":
            return noise + wire
        if kind == "replace":
            return noise + b"\r"
        return wire[: len(wire) // 2]

    def _write(self, data: bytes) -> None:
        with self._lock:
            master = self._master
        if master is None:
            return
        deadline = time.monotonic() + 2.0  # a long reply (a storage read-out) goes as the reader takes it
        while data:
            try:
                data = data[os.write(master, data) :]
            except BlockingIOError:
                if time.monotonic() > deadline:
                    return  # nobody reads: the rest is lost, as on a real line
                select.select([], [master], [], 0.05)
            except OSError:
                return

    def _log(self, exchange: FakeExchange) -> None:
        with self._lock:
            self.exchanges.append(exchange)
