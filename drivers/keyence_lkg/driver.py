"""The LK-G laser displacement sensor behind :class:`cellctl.ports.DisplacementSensor`.

One command is in flight at a time (an asyncio lock), every exchange has a timeout, and every
call has an overall deadline. What makes it safe on a real serial line:

- **Which reply answers which command.** The controller answers strictly in order, one reply per
  command it received. The driver keeps the commands whose replies it has not seen yet
  (``outstanding``) and gives each incoming reply to the oldest outstanding command it can belong
  to (same echo, or an ``ER`` naming the same main command); when a later command is answered,
  every earlier one is settled (answered already, or lost). A reply is taken as the answer to the
  current command only if no older command that could produce the same reply is still
  outstanding. Before sending a command while such an older one is outstanding (after a lost or
  garbled reply) the driver sends a *barrier* (a harmless read with a different main command)
  and waits for a reply that settles every such older command: its own, or that of an older
  barrier still outstanding (lost in the same silence), since a reply settles everything sent
  before the command it answers. A late reply with the right echo but a stale value is never
  taken as the current reading.
- **Garbage.** A line that is not a valid reply is dropped, the input flushed and the command
  retried (behind a barrier). Three garbled replies in a row end the call with DeviceProtocolError
  naming the last problem (a wrong baud rate or display unit shows up here).
- **A vanished port.** End of file or EIO on the port closes it; the call then reopens the same
  path as the reconnect policy allows (attempts, interval) within its deadline, resynchronises
  and carries on; when the policy gives up: DeviceDisconnected.
- **Modes.** A measurement refused with the status error (the controller was left in
  communication mode) is followed by ``R0`` and one retry. Settings change inside
  :meth:`KeyenceLkgSensor.communication_mode` (``Q0`` ... ``R0``); ``ER`` on ``Q0``/``R0`` with the
  status error means "already in that mode".

Over range and no value are statuses of the reading, never exceptions.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from dataclasses import dataclass
from typing import Any, AsyncIterator, Callable, Final, Literal, Mapping, Sequence

from cellctl.ports import (
    DeviceBusy,
    DeviceDisconnected,
    DeviceError,
    DeviceProtocolError,
    DeviceRejected,
    DeviceTimeout,
    DistanceReading,
    LaserStatus,
)
from keyence_lkg.codec import (
    MAX_REPLY_CHARS,
    Command,
    ErrorReply,
    GarbledReply,
    Reply,
    decode_values,
    dialect_for,
    may_answer,
    parse_line,
    payload_of,
)
from keyence_lkg.link import LinkLost, LinkStats, LinkTimeout, ReconnectPolicy, SerialLine
from keyence_lkg.storage import LkgStorage
from keyence_lkg.units import UnitFormat, ValueKind, WireValue, unit_format

_log = logging.getLogger(__name__)

DisplacementPositive = Literal["away_from_head", "toward_head"]
BAUD_RATES: Final = (9600, 19200, 38400, 57600, 115200)
MAX_GARBLED_IN_A_ROW: Final = 3
MAX_OUTSTANDING: Final = 64  # a command unanswered for 64 exchanges is forgotten


@dataclass(frozen=True)
class _Answer:
    """The reply that answered a command: an error, or the payload (values decoded)."""

    error: ErrorReply | None
    fields: tuple[str, ...]
    values: tuple[WireValue, ...]
    arrived_s: float


class _Pending:
    """One sent command awaiting its reply (compared by identity: each send is its own)."""

    __slots__ = ("command",)

    def __init__(self, command: Command) -> None:
        self.command = command


@dataclass
class _Call:
    """Bookkeeping of one public call: its deadline and what went wrong so far."""

    deadline: float
    reopen_attempts: int = 0
    garbled_in_a_row: int = 0
    last_problem: str = ""
    silent_exchanges: int = 0
    saw_link_loss: bool = False


class KeyenceLkgSensor(LkgStorage):
    """A Keyence LK-G controller (LK-G3001 or LK-G5001) on a serial port; it stores readings on the move (LkgStorage).

    Args:
        port: the serial device path (a udev name /dev/serial/by-id/..., or the fake's pseudo-terminal).
        dialect: "LK-G3001" or "LK-G5001"; never guessed.
        display_unit: the controller's minimum display unit (the reply does not carry it).
        reference_distance_mm: distance along the laser from its origin r at which the OUT reads 0.
        displacement_positive: which way a positive value points ("away_from_head": farther).
        output: the OUT number of the head on the alignment laser (1-based).
        baud: the controller's RS-232C baud rate.
        exchange_timeout_s: the longest wait for one reply to a measurement or setting command.
        mode_change_timeout_s: the longest wait for a reply to Q0/R0 (R0: 600 ms and more on an LK-G5001).
        reconnect: how to reopen a vanished port.
        name: the device's name in errors.
        clock: the cell's clock (s): the storage's start is on it (:class:`cellctl.ports.StoredReadings`).
    """

    def __init__(
        self,
        *,
        port: str,
        dialect: str,
        display_unit: str,
        reference_distance_mm: float,
        displacement_positive: DisplacementPositive,
        output: int = 1,
        baud: int = 115200,
        exchange_timeout_s: float = 0.5,
        mode_change_timeout_s: float = 3.0,
        reconnect: ReconnectPolicy | None = None,
        name: str = "laser",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not port:
            raise ValueError("port must name the serial device, e.g. /dev/serial/by-id/usb-...")
        self._dialect = dialect_for(dialect)
        self._unit: UnitFormat = unit_format(display_unit)
        if not (math.isfinite(reference_distance_mm) and reference_distance_mm > 0):
            raise ValueError(f"reference_distance_mm must be a positive number, got {reference_distance_mm!r}")
        if displacement_positive not in ("away_from_head", "toward_head"):
            raise ValueError(
                f"displacement_positive must be 'away_from_head' or 'toward_head', got {displacement_positive!r}"
            )
        if baud not in BAUD_RATES:
            raise ValueError(f"baud {baud!r} is not one the LK-G offers: {', '.join(map(str, BAUD_RATES))}")
        for label, value in (("exchange_timeout_s", exchange_timeout_s), ("mode_change_timeout_s", mode_change_timeout_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{label} must be a positive number of seconds, got {value!r}")
        self.output = self._dialect.check_out(output)
        self.name = name
        self.reference_distance_mm = float(reference_distance_mm)
        self._sign = 1.0 if displacement_positive == "away_from_head" else -1.0
        self.exchange_timeout_s = float(exchange_timeout_s)
        self.mode_change_timeout_s = float(mode_change_timeout_s)
        self.reconnect = reconnect or ReconnectPolicy()
        self.clock = clock
        self._line = SerialLine(port, baud)
        self._lock = asyncio.Lock()
        self._outstanding: list[_Pending] = []
        self._read_command = self._dialect.read_output(self.output)
        self._barriers = self._dialect.barrier_commands()
        self._settings_session = False
        self._closed = False
        self._ever_opened = False
        self.stats = LinkStats()

    @classmethod
    def from_config(
        cls, config: Mapping[str, Any], *, name: str = "laser", clock: Callable[[], float] = time.monotonic
    ) -> "KeyenceLkgSensor":
        """Build from a ``[devices.laser]`` mapping (``kind = "keyence_lkg"``, e.g. ``model_dump()``)."""
        cfg = dict(config)
        cfg.pop("kind", None)
        reconnect = cfg.pop("reconnect", None)
        policy = ReconnectPolicy(**reconnect) if isinstance(reconnect, Mapping) else reconnect
        return cls(**cfg, reconnect=policy, name=name, clock=clock)

    @property
    def dialect(self) -> str:
        """The controller model this driver speaks to."""
        return self._dialect.name

    @property
    def port(self) -> str:
        """The serial device path."""
        return self._line.port

    def identity(self) -> dict[str, str]:
        """What this sensor is (:class:`cellctl.ports.Identified`): the controller model it speaks
        to, the serial port, the OUT read and the display unit (from the configuration: the LK-G
        does not report them)."""
        return {
            "dialect": self._dialect.name,
            "port": self._line.port,
            "output": str(self.output),
            "display_unit": self._unit.name,
        }

    @property
    def bytes_on_wire(self) -> tuple[int, int]:
        """Bytes written and read since the driver was made (for the benchmark)."""
        return self._line.bytes_written, self._line.bytes_read

    # ------------------------------------------------------------------------------------------
    # DisplacementSensor

    async def read(self, *, timeout_s: float) -> DistanceReading:
        """One reading of the configured OUT as a distance along the laser from r (eq. 1)."""
        answer = await self._run(self._measure, self._read_command, timeout_s=timeout_s)
        return self._reading(answer.values[0], self.output, answer.arrived_s)

    async def ping(self, *, timeout_s: float) -> float:
        """A measurement read as a round trip (any reply counts); returns its duration in seconds."""
        start = time.monotonic()
        await self._run(self._exchange, self._read_command, timeout_s=timeout_s)
        return time.monotonic() - start

    async def close(self) -> None:
        """Close the port; later calls raise DeviceDisconnected. Safe to call twice."""
        self._closed = True
        self._line.close()

    # ------------------------------------------------------------------------------------------
    # more of the controller

    async def connect(self, *, timeout_s: float) -> None:
        """Open the port now and check the controller answers a measurement (otherwise the first call does)."""
        await self.ping(timeout_s=timeout_s)

    async def read_displacements(
        self, outs: Sequence[int] | None = None, *, timeout_s: float
    ) -> dict[int, WireValue]:
        """Raw displacements (mm, display offset included) of several OUTs in one exchange.

        ``outs=None`` reads every OUT (``M0`` / ``MA``). These are not mapped to distances: other
        OUTs may belong to other heads with their own reference distance.
        """
        if outs is None and self._dialect.name == "LK-G5001":
            command = self._dialect.read_all()  # type: ignore[attr-defined]
            answer = await self._run(self._measure, command, timeout_s=timeout_s)
            return {i + 1: v for i, v in enumerate(answer.values)}
        wanted = tuple(outs) if outs is not None else tuple(range(1, self._dialect.max_out + 1))
        command, order = self._dialect.read_outputs(wanted)
        answer = await self._run(self._measure, command, timeout_s=timeout_s)
        got = dict(zip(order, answer.values, strict=True))
        return {o: got[o] for o in wanted}

    @contextlib.asynccontextmanager
    async def communication_mode(self, *, timeout_s: float) -> AsyncIterator["KeyenceLkgSensor"]:
        """Enter communication mode (``Q0``) for settings and return to measuring (``R0``) on exit.

        Measuring stops meanwhile: :meth:`read` raises DeviceRejected inside the block.
        """
        await self._run(self._mode_change, self._dialect.communication_mode(), timeout_s=timeout_s)
        self._settings_session = True
        try:
            yield self
        finally:
            self._settings_session = False
            await self._run(self._mode_change, self._dialect.general_mode(), timeout_s=timeout_s)

    async def read_setting(self, ident: str, *params: str, timeout_s: float) -> tuple[str, ...]:
        """``SR,<ident>,<params>``: the fields the controller returns after the request's own."""
        answer = await self._run(self._setting, self._dialect.read_setting(ident, *params), timeout_s=timeout_s)
        return answer.fields

    async def write_setting(self, ident: str, *params: str, timeout_s: float) -> None:
        """``SW,<ident>,<params>`` (only in communication mode; the controller refuses it otherwise)."""
        await self._run(self._setting, self._dialect.write_setting(ident, *params), timeout_s=timeout_s)

    # ------------------------------------------------------------------------------------------
    # one call

    async def _run(self, op: Any, command: Command, *, timeout_s: float) -> _Answer:
        if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s must be a positive number of seconds, got {timeout_s!r}")
        loop = asyncio.get_running_loop()
        call = _Call(deadline=loop.time() + timeout_s)
        if self._lock.locked():
            try:
                await asyncio.wait_for(self._lock.acquire(), timeout_s)
            except TimeoutError:
                raise DeviceBusy(self.name, f"busy: another command did not finish within {timeout_s:g} s") from None
        else:
            await self._lock.acquire()
        try:
            return await op(command, call)
        finally:
            self._lock.release()

    async def _measure(self, command: Command, call: _Call) -> _Answer:
        answer = await self._exchange(command, call)
        if answer.error is not None and answer.error.code == self._dialect.status_error_code and not self._settings_session:
            # left in communication mode (by another tool, or a session cut short): measure again after R0
            self.stats.mode_recoveries += 1
            _log.warning("%s: %s refused in communication mode; sending R0", self.name, command.text)
            await self._mode_change(self._dialect.general_mode(), call)
            answer = await self._exchange(command, call)
        self._raise_if_error(command, answer)
        return answer

    async def _setting(self, command: Command, call: _Call) -> _Answer:
        answer = await self._exchange(command, call)
        self._raise_if_error(command, answer)
        return answer

    async def _mode_change(self, command: Command, call: _Call) -> _Answer:
        answer = await self._exchange(command, call, exchange_timeout_s=self.mode_change_timeout_s)
        if answer.error is not None and answer.error.code == self._dialect.status_error_code:
            return answer  # already in that mode
        self._raise_if_error(command, answer)
        return answer

    def _raise_if_error(self, command: Command, answer: _Answer) -> None:
        if answer.error is None:
            return
        code = answer.error.code
        hint = ""
        if code == self._dialect.status_error_code:
            hint = " (settings need communication_mode(); measuring needs general mode)"
        raise DeviceRejected(self.name, f"{command.text} refused: {self._dialect.describe_error(code)}{hint}", code)

    # ------------------------------------------------------------------------------------------
    # one exchange, with resynchronisation and reconnection

    async def _exchange(self, command: Command, call: _Call, *, exchange_timeout_s: float | None = None) -> _Answer:
        loop = asyncio.get_running_loop()
        per_exchange = self.exchange_timeout_s if exchange_timeout_s is None else exchange_timeout_s
        if command.max_reply_chars > MAX_REPLY_CHARS:  # a storage read-out: twice its time on the wire (8N1)
            per_exchange += 2.0 * 10.0 * command.max_reply_chars / self._line.baud
        while True:
            if loop.time() >= call.deadline:
                raise self._deadline_error(command, call)
            await self._ensure_open(call)
            xdeadline = min(call.deadline, loop.time() + per_exchange)
            try:
                if any(p.command.main == command.main for p in self._outstanding):
                    await self._resync(command, xdeadline)
                    continue
                answer = await self._send_and_await(command, xdeadline, decode=True)
                call.garbled_in_a_row = 0
                return answer
            except LinkTimeout:
                self.stats.timeouts += 1
                call.silent_exchanges += 1
                call.last_problem = f"no reply within {per_exchange:g} s"
            except GarbledReply as exc:
                call.garbled_in_a_row += 1
                call.last_problem = f"garbled reply: {exc}"
                _log.warning("%s: %s", self.name, call.last_problem)
                self._line.flush_input()
                if call.garbled_in_a_row >= MAX_GARBLED_IN_A_ROW:
                    raise DeviceProtocolError(
                        self.name,
                        f"{call.garbled_in_a_row} garbled replies in a row to {command.text}; last: {exc}. "
                        f"Check the baud rate ({self._line.baud}), the cable, devices.laser.dialect "
                        f"({self._dialect.name}) and devices.laser.display_unit ({self._unit.name})",
                    ) from exc
            except LinkLost as exc:
                call.saw_link_loss = True
                call.last_problem = str(exc)
                _log.warning("%s: link lost: %s", self.name, exc)
                self._line.close()

    async def _send_and_await(
        self, command: Command, deadline: float, *, decode: bool, settling: str | None = None
    ) -> _Answer:
        """Send ``command`` and wait for its reply; with ``settling`` (a barrier), return as soon as a
        reply leaves no command of that main outstanding (the barrier's value is never used)."""
        self._line.flush_input()
        pending = _Pending(command)
        self._outstanding.append(pending)
        if len(self._outstanding) > MAX_OUTSTANDING:
            del self._outstanding[0]
        self.stats.exchanges += 1
        self._line.max_line = command.max_reply_chars
        await self._line.write(command.wire, deadline)
        while True:
            raw, arrived = await self._line.read_line(deadline)
            try:
                reply = parse_line(raw, command.max_reply_chars)
            except GarbledReply:
                self.stats.garbled_lines += 1
                raise
            owner = self._settle(reply)
            if owner is None:
                self.stats.unsolicited_lines += 1
                _log.info("%s: unsolicited line %r ignored", self.name, raw)
                continue
            if owner is not pending:
                self.stats.late_replies += 1
                if settling is not None and not any(p.command.main == settling for p in self._outstanding):
                    return _Answer(None, (), (), arrived)  # an older barrier answered: all before it settled
                continue
            if isinstance(reply, ErrorReply):
                return _Answer(reply, (), (), arrived)
            if not decode:
                return _Answer(None, (), (), arrived)
            if command.payload == "values":
                return _Answer(None, (), tuple(decode_values(command, reply, self._unit)), arrived)
            return _Answer(None, payload_of(command, reply), (), arrived)

    def _settle(self, reply: Reply | ErrorReply) -> _Pending | None:
        """The oldest outstanding command this reply can belong to; it and all before it are settled."""
        for i, pending in enumerate(self._outstanding):
            if may_answer(pending.command, reply):
                del self._outstanding[: i + 1]
                return pending
        return None

    async def _resync(self, command: Command, deadline: float) -> None:
        """Send a barrier (a read with another main command) and wait until a reply settles every
        outstanding command of ``command``'s main (the barrier's, or an older barrier's reply)."""
        self.stats.resyncs += 1
        busy = {p.command.main for p in self._outstanding}
        candidates = [b for b in self._barriers if b.main != command.main]
        barrier = next((b for b in candidates if b.main not in busy), candidates[0])
        await self._send_and_await(barrier, deadline, decode=False, settling=command.main)

    async def _ensure_open(self, call: _Call) -> None:
        if self._closed:
            raise DeviceDisconnected(self.name, f"closed; {self._line.port} is no longer used")
        if self._line.is_open:
            return
        self._line.close()
        loop = asyncio.get_running_loop()
        while True:
            call.reopen_attempts += 1
            try:
                self._line.open()
            except LinkLost as exc:
                gave_up = call.reopen_attempts >= self.reconnect.attempts
                if gave_up or loop.time() + self.reconnect.interval_s >= call.deadline:
                    reason = (
                        f"after {call.reopen_attempts} attempt(s)"
                        if gave_up
                        else f"within the call's timeout ({call.reopen_attempts} attempt(s))"
                    )
                    raise DeviceDisconnected(
                        self.name,
                        f"{exc}; the port did not come back {reason}. "
                        f"Check the USB serial adapter and devices.laser.port",
                    ) from exc
                await asyncio.sleep(self.reconnect.interval_s)
                continue
            if self._ever_opened:
                self.stats.reconnects += 1
                _log.warning("%s: reopened %s", self.name, self._line.port)
            self._ever_opened = True
            return

    def _deadline_error(self, command: Command, call: _Call) -> DeviceError:
        what = call.last_problem or "no time left"
        if call.saw_link_loss and not self._line.is_open:
            return DeviceDisconnected(self.name, f"{command.text}: port lost ({what}) and not back before the deadline")
        return DeviceTimeout(
            self.name,
            f"no valid reply to {command.text} before the call's deadline ({what}; "
            f"{call.silent_exchanges} exchange(s) without reply). Check the cable, power and baud rate "
            f"({self._line.baud})",
        )

    # ------------------------------------------------------------------------------------------

    def _reading(self, value: WireValue, out: int, arrived_s: float) -> DistanceReading:
        if value.kind is ValueKind.NUMBER:
            assert value.mm is not None
            distance = self.reference_distance_mm + self._sign * value.mm
            return DistanceReading(distance, LaserStatus.OK, arrived_s, out)
        if value.kind is ValueKind.NO_VALUE:
            status = LaserStatus.NO_VALUE
        elif (value.kind is ValueKind.OVER_RANGE_PLUS) == (self._sign > 0):
            status = LaserStatus.OVER_RANGE_FAR
        else:
            status = LaserStatus.OVER_RANGE_NEAR
        return DistanceReading(None, status, arrived_s, out)
