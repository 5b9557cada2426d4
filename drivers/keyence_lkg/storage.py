"""The LK-G's data storage: the controller stores a reading every storage cycle by itself, the PC
reads them out afterwards (``AQ`` clear, ``AS`` start, ``AP`` stop, ``AN`` status, ``AO`` output).

This is how the cell reads the wall on the move (:class:`cellctl.ports.StoringSensor`): polling
over RS-232C gives a reading every few ms at best, with the serial line's jitter in its time;
storage gives them on the controller's own clock at an exact cycle.

The storage cycle is the sampling cycle (setting ``CA``) times a multiplier the storage setup
names by a code. Setup per dialect (in communication mode, ``Q0`` ... ``R0``):

- LK-G5001: ``SW,CF,<7-digit count>,<2-digit cycle code>`` and ``SW,OK,<nn>,1`` (store OUT nn);
- LK-G3001: ``SW,CI,<OUT>,<5-digit count>,<cycle code>``.

Sources (../shared/reference/keyence_lkg.md A7, A8): working code for both setups; the multiplier
codes 2, 3, 4, 6, 9 for x5, x10, x20, x100, x1000 on the LK-G5001. The others follow the same
1-2-5 series (an inference), and the LK-G3001 is taken to use the same codes (MECODE sends 0: x1).
``AN`` answers ``AN,<storing 0/1>,<count stored>``; ``AO,<OUT>`` answers ``AO,<v>,<v>,...`` in the
measured-value format (``XXXXXXXX`` / ``+-FFFFFFF`` where a reading had no value).
"""

from __future__ import annotations

import functools
import math
import time
from typing import TYPE_CHECKING, Final

from cellctl.ports import DeviceProtocolError, DeviceRejected, LaserStatus, StoredReadings
from keyence_lkg.codec import MAX_REPLY_CHARS, Command, LkgDialect

if TYPE_CHECKING:
    from keyence_lkg.driver import KeyenceLkgSensor

# Sampling cycle (setting CA) by code, in microseconds.
SAMPLING_CYCLE_US: Final[dict[str, tuple[float, ...]]] = {
    "LK-G3001": (20.0, 50.0, 100.0, 200.0, 500.0, 1000.0),
    "LK-G5001": (2.55, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0),
}
# Storage cycle = sampling cycle x STORAGE_MULTIPLIERS[code].
STORAGE_MULTIPLIERS: Final = (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000)
# The most readings one storage holds (the setup's count field: 5 digits on the LK-G3001, 7 on the LK-G5001).
MAX_STORED: Final[dict[str, int]] = {"LK-G3001": 65_535, "LK-G5001": 1_200_000}
VALUE_CHARS: Final = 9  # one stored value on the wire: 8 characters and its comma


def storage_cycle_code(dialect: str, sampling_code: int, cycle_s: float) -> tuple[int, float]:
    """The multiplier code whose storage cycle is ``cycle_s`` at this sampling cycle, and that cycle in s.

    ValueError naming the cycles this sampling cycle offers when none matches within 0.1 %.
    """
    sampling_s = SAMPLING_CYCLE_US[dialect][sampling_code] * 1e-6
    for code, k in enumerate(STORAGE_MULTIPLIERS):
        if math.isclose(sampling_s * k, cycle_s, rel_tol=1e-3):
            return code, sampling_s * k
    offered = ", ".join(f"{sampling_s * k * 1e3:g}" for k in STORAGE_MULTIPLIERS)
    raise ValueError(
        f"a storage cycle of {cycle_s * 1e3:g} ms is not the sampling cycle ({sampling_s * 1e6:g} us, setting CA) "
        f"times a storage multiplier; choose one of {offered} ms (process.align.sweep.storage_cycle_s)"
    )


def setup_commands(dialect: LkgDialect, out: int, count: int, code: int) -> tuple[Command, ...]:
    """The settings that make the controller store ``count`` readings of ``out`` at cycle ``code``."""
    if not 1 <= count <= MAX_STORED[dialect.name]:
        raise ValueError(f"a storage holds 1..{MAX_STORED[dialect.name]} readings on the {dialect.name}, asked for {count}")
    o = dialect.out_field(out)
    if dialect.name == "LK-G3001":
        return (dialect.write_setting("CI", o, f"{count:05d}", str(code)),)
    return (dialect.write_setting("CF", f"{count:07d}", f"{code:02d}"), dialect.write_setting("OK", o, "1"))


def storage_command(main: str) -> Command:
    """``AQ`` (clear), ``AS`` (start) or ``AP`` (stop): each answered by its echo."""
    return Command(main, main, main, "none")


STATUS: Final = Command("AN", "AN", "AN", "fields")


def output_command(dialect: LkgDialect, out: int, count: int) -> Command:
    """``AO,<OUT>``: the ``count`` stored readings of ``out`` in one line."""
    return Command(
        f"AO,{dialect.out_field(out)}", "AO", "AO", "values", count, max_reply_chars=MAX_REPLY_CHARS + VALUE_CHARS * count
    )


def parse_status(fields: tuple[str, ...], name: str) -> tuple[bool, int]:
    """``AN,<storing>,<count>``: whether it still stores, and how many readings it holds."""
    if len(fields) < 2 or fields[0] not in ("0", "1") or not fields[1].isdigit():
        raise DeviceProtocolError(name, f"storage status AN,{','.join(fields)} is not AN,<0/1>,<count>")
    return fields[0] == "1", int(fields[1])


def _left_until(deadline: float) -> float:
    """Seconds until ``deadline`` (time.monotonic()), at least 1 ms: each exchange of a call gets what is left."""
    return max(1e-3, deadline - time.monotonic())


class LkgStorage:
    """Data storage for :class:`keyence_lkg.driver.KeyenceLkgSensor` (a mixin: it uses the driver's exchanges).

    The setup (a trip through communication mode, which takes 0.6 s and more on an LK-G5001) is
    written only when the cycle changes or a sweep needs more readings than it holds (``AP`` ends
    a shorter one); a sweep then costs ``AQ`` and ``AS`` before and ``AP``, ``AN`` and ``AO`` after.
    ``AO`` is 9 bytes per reading on the wire: 1,000 readings take 0.8 s at 115200 baud, and
    :meth:`stop_storage` allows twice that beyond its timeout.
    """

    _storage_setup: tuple[int, int, int] | None = None  # (out, count, code) last written
    _storage_cycle_s: float = 0.0
    _storage_started_s: float = 0.0
    _storage_asked: int = 0  # the count this sweep asked for (the setup may hold more)
    _storage_window: tuple[float, float] | None = None  # (earliest, latest) start on the driver's clock (s)

    async def start_storage(self: KeyenceLkgSensor, *, cycle_s: float, count: int, timeout_s: float) -> float:
        """Clear the storage and store the configured OUT every ``cycle_s`` (at most ``count``).

        Returns the instant of the first reading on the driver's ``clock``: the controller starts when it
        has ``AS``, so its echo's arrival less the echo's own time on the wire. The host's delay in
        noticing the echo is in it too, anew in every storage: :meth:`storage_start_window` bounds it.
        """
        deadline = time.monotonic() + timeout_s
        left = functools.partial(_left_until, deadline)
        setup = self._storage_setup
        if setup is None or setup[0] != self.output or setup[1] < count or not math.isclose(self._storage_cycle_s, cycle_s, rel_tol=1e-3):
            async with self.communication_mode(timeout_s=left()):
                fields = await self.read_setting("CA", timeout_s=left())
                sampling = int(fields[-1])
                if not 0 <= sampling < len(SAMPLING_CYCLE_US[self.dialect]):
                    raise DeviceProtocolError(self.name, f"sampling cycle code CA = {fields[-1]} is not one the {self.dialect} has")
                code, actual_s = storage_cycle_code(self.dialect, sampling, cycle_s)
                for command in setup_commands(self._dialect, self.output, count, code):
                    await self._run(self._setting, command, timeout_s=left())
            self._storage_setup, self._storage_cycle_s = (self.output, count, code), actual_s
        self._storage_asked = count
        try:  # not _measure: its R0 would take a storage that runs for communication mode
            await self._run(self._setting, storage_command("AQ"), timeout_s=left())
        except DeviceRejected as err:  # a storage left running (a sweep cut short) refuses AQ: stop it, then clear
            if err.code != self._dialect.status_error_code:
                raise
            await self._run(self._measure, storage_command("AP"), timeout_s=left())  # (or R0 first, if in communication mode)
            await self._run(self._measure, storage_command("AQ"), timeout_s=left())
        called, exchanges = time.monotonic(), self.stats.exchanges
        answer = await self._run(self._measure, storage_command("AS"), timeout_s=left())
        # The controller started between the AS's first byte leaving the PC and its echo's arrival as noticed here;
        # an exchange sent again (no echo in time, a mode recovery) may have started it with the first: from the call.
        written = self._line.write_started_s if self.stats.exchanges == exchanges + 1 else called
        started_mono = answer.arrived_s - 10.0 * len(b"AS\r") / self._line.baud  # 8N1, on time.monotonic()
        to_clock = self.clock() - time.monotonic()
        self._storage_started_s = to_clock + started_mono
        self._storage_window = (to_clock + min(written, started_mono), to_clock + answer.arrived_s)
        return self._storage_started_s

    def storage_start_window(self) -> tuple[float, float] | None:
        """The earliest and latest instant (s, the driver's clock) the last storage can have started at: the
        ``AS`` command's write and its echo's arrival as the host noticed it. The start returned lies within;
        how late the host noticed the echo (its event loop busy) widens the window, so a sweep can tell
        how well its start is known. None before a storage started."""
        return self._storage_window

    async def stop_storage(self: KeyenceLkgSensor, *, timeout_s: float) -> StoredReadings:
        """Stop storing and read out what was stored, as distances along the laser (None: no value)."""
        deadline = time.monotonic() + timeout_s
        left = functools.partial(_left_until, deadline)
        await self._run(self._measure, storage_command("AP"), timeout_s=left())
        answer = await self._run(self._measure, STATUS, timeout_s=left())
        _, count = parse_status(answer.fields, self.name)  # all it holds comes out; the first asked-for are kept
        distances: tuple[float | None, ...] = ()
        if count:
            command = output_command(self._dialect, self.output, count)
            wire_s = 10.0 * command.max_reply_chars / self._line.baud  # 8N1: ten bits a character
            answer = await self._run(self._measure, command, timeout_s=max(left(), 2.0 * wire_s))
            readings = [self._reading(v, self.output, answer.arrived_s) for v in answer.values]
            distances = tuple(r.distance_mm if r.status is LaserStatus.OK else None for r in readings[: self._storage_asked])
        return StoredReadings(started_s=self._storage_started_s, cycle_s=self._storage_cycle_s, distances_mm=distances)
