"""Commands and replies of the LK-G controllers' RS-232C protocol, for both dialects.

Framing (manual p. 5-5): ASCII, one command ``Main[,p1[,p2...]]`` then CR; the reply echoes the
main command (and identifiers) as its header, or is ``ER,<main>,<code>`` CR. Upper and lower case
are both accepted by the controller; this codec always sends upper case.

The two controllers speak different dialects, chosen by configuration and never guessed:

- LK-G3001: ``M1``/``M2`` read OUT1/OUT2 (``M1,<v>``), ``M0`` reads both (``M0,<v1>,<v2>``);
  OUT numbers are one digit.
- LK-G5001: ``MS,nn`` reads one OUT (``MS,nn,<v>``), ``MM,<12-char mask>`` a selection
  (``MM,<mask>,<v>...``), ``MA`` all of them (``MA,<v1>,<v2>...``); OUT numbers are two digits.

Both: ``Q0`` enters communication mode (settings), ``R0`` returns to general mode (measuring),
``SW,<id>,...`` writes a setting (reply ``SW,<id>``), ``SR,<id>,...`` reads one (reply
``SR,<id>,...,<value>``).
"""

from __future__ import annotations

import re
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Final, Literal

from keyence_lkg.errors import STATUS_ERROR, Dialect, describe_error
from keyence_lkg.units import UnitFormat, WireValue, parse_value

PayloadKind = Literal["none", "values", "fields"]

MAX_REPLY_CHARS: Final = 256  # the longest reply (MA with 12 OUTs) is 111 characters
_PRINTABLE_RE: Final = re.compile(r"[\x20-\x7e]+")
_IDENT_RE: Final = re.compile(r"[A-Z0-9]{1,4}")
_PARAM_RE: Final = re.compile(r"[A-Za-z0-9+\-.]{1,16}")


@dataclass(frozen=True)
class Command:
    """One request and the shape of the reply that answers it.

    Attributes:
        text: the request without the CR, upper case.
        main: the main command (first field); an error reply names it.
        echo: the header a normal reply starts with (the reply is ``echo`` or ``echo,...``).
        payload: what follows the echo: nothing, measurement values, or setting fields.
        value_count: for "values", the exact number of values, or None for "one or more".
        max_reply_chars: the longest reply it may get (a storage read-out is long).
    """

    text: str
    main: str
    echo: str
    payload: PayloadKind
    value_count: int | None = None
    max_reply_chars: int = MAX_REPLY_CHARS

    @property
    def wire(self) -> bytes:
        """The bytes to send."""
        return self.text.encode("ascii") + b"\r"


@dataclass(frozen=True)
class Reply:
    """A normal reply: its full text and its comma-separated fields."""

    text: str
    fields: tuple[str, ...]


@dataclass(frozen=True)
class ErrorReply:
    """``ER,<main>,<code>``: the controller refused the command ``main``."""

    main: str
    code: str


class GarbledReply(ValueError):
    """A line that is no reply the protocol allows (noise, a cut-off reply, a wrong baud rate)."""


def parse_line(line: bytes, max_chars: int = MAX_REPLY_CHARS) -> Reply | ErrorReply:
    """Classify one CR-terminated line (without its CR); raises GarbledReply for anything else."""
    if not line:
        raise GarbledReply("empty line")
    if len(line) > max_chars:
        raise GarbledReply(f"line of {len(line)} bytes without CR")
    try:
        text = line.decode("ascii")
    except UnicodeDecodeError:
        raise GarbledReply(f"non-ASCII bytes {line[:40]!r}") from None
    if _PRINTABLE_RE.fullmatch(text) is None:
        raise GarbledReply(f"control characters in {text[:40]!r}")
    fields = tuple(text.split(","))
    if fields[0] == "ER":
        if len(fields) != 3 or re.fullmatch(r"[0-9]{2}", fields[2]) is None or not fields[1]:
            raise GarbledReply(f"malformed error reply {text!r}")
        return ErrorReply(fields[1].upper(), fields[2])
    if any(not f for f in fields):
        raise GarbledReply(f"empty field in {text!r}")
    return Reply(text, fields)


SETTING_COMMANDS = ("SW", "SR")
"""Setting change / check: some controllers (and the ISIS emulator) head their errors with the setting's
identifier (``ER,OF,00`` for ``SW,OF,...``) where the manual says the main command (``ER,SW,00``)."""


def may_answer(command: Command, reply: Reply | ErrorReply) -> bool:
    """True if ``reply`` has the header of a reply to ``command``: its echo, or an error naming its main command
    (or, for a setting command, its setting identifier)."""
    if isinstance(reply, ErrorReply):
        if reply.main == command.main:
            return True
        fields = command.text.split(",")
        return command.main in SETTING_COMMANDS and len(fields) > 1 and reply.main == fields[1].upper()
    return reply.text == command.echo or reply.text.startswith(command.echo + ",")


def payload_of(command: Command, reply: Reply) -> tuple[str, ...]:
    """The fields after the echo, checked against the command's payload shape (GarbledReply if not)."""
    n_echo = command.echo.count(",") + 1
    rest = reply.fields[n_echo:]
    if command.payload == "none" and rest:
        raise GarbledReply(f"{reply.text!r}: no payload expected after {command.echo!r}")
    if command.payload == "fields" and not rest:
        raise GarbledReply(f"{reply.text!r}: setting fields expected after {command.echo!r}")
    if command.payload == "values":
        if command.value_count is not None and len(rest) != command.value_count:
            raise GarbledReply(f"{reply.text!r}: {command.value_count} value(s) expected, got {len(rest)}")
        if not rest:
            raise GarbledReply(f"{reply.text!r}: no values")
    return rest


def decode_values(command: Command, reply: Reply, unit: UnitFormat) -> list[WireValue]:
    """The measured values of a reply to a measurement command (GarbledReply if any is malformed)."""
    try:
        return [parse_value(token, unit) for token in payload_of(command, reply)]
    except ValueError as exc:
        raise GarbledReply(f"{reply.text!r}: {exc}") from exc


def _check_ident(ident: str) -> str:
    ident = ident.upper()
    if _IDENT_RE.fullmatch(ident) is None:
        raise ValueError(f"setting identifier {ident!r} must be 1-4 letters or digits (e.g. 'CA', 'OF')")
    return ident


def _check_params(params: tuple[str, ...]) -> tuple[str, ...]:
    for p in params:
        if _PARAM_RE.fullmatch(p) is None:
            raise ValueError(f"setting parameter {p!r} must be 1-16 characters of letters, digits, '+', '-', '.'")
    return tuple(p.upper() for p in params)


class LkgDialect(ABC):
    """The commands of one controller model. Use :func:`dialect_for`."""

    def __init__(self, name: Dialect, max_out: int, out_width: int) -> None:
        self.name: Dialect = name
        self.max_out = max_out
        self._out_width = out_width

    @property
    def status_error_code(self) -> str:
        """The code of "not allowed in this mode"."""
        return STATUS_ERROR[self.name]

    def describe_error(self, code: str) -> str:
        """What an error code means on this controller."""
        return describe_error(self.name, code)

    def out_field(self, out: int) -> str:
        """An OUT number as this controller writes it ("1" or "01")."""
        self.check_out(out)
        return f"{out:0{self._out_width}d}"

    def check_out(self, out: int) -> int:
        """``out`` if this controller has it, else ValueError naming the range."""
        if not isinstance(out, int) or isinstance(out, bool) or not 1 <= out <= self.max_out:
            raise ValueError(f"OUT number {out!r} is not valid on the {self.name} (1..{self.max_out})")
        return out

    # mode
    def communication_mode(self) -> Command:
        """``Q0``: enter communication (setting) mode; measuring stops."""
        return Command("Q0", "Q0", "Q0", "none")

    def general_mode(self) -> Command:
        """``R0``: back to general (measuring) mode."""
        return Command("R0", "R0", "R0", "none")

    # settings
    def write_setting(self, ident: str, *params: str) -> Command:
        """``SW,<id>,<params>``; the reply is ``SW,<id>``."""
        ident = _check_ident(ident)
        params = _check_params(params)
        if not params:
            raise ValueError(f"writing setting {ident} needs at least one parameter")
        return Command(",".join(("SW", ident, *params)), "SW", f"SW,{ident}", "none")

    def read_setting(self, ident: str, *params: str) -> Command:
        """``SR,<id>[,<params>]``; the reply repeats the request and adds the value(s)."""
        ident = _check_ident(ident)
        text = ",".join(("SR", ident, *_check_params(params)))
        return Command(text, "SR", text, "fields")

    # measurement (dialect specific)
    @abstractmethod
    def read_output(self, out: int) -> Command:
        """Read one OUT."""

    @abstractmethod
    def read_outputs(self, outs: tuple[int, ...]) -> tuple[Command, tuple[int, ...]]:
        """Read several OUTs in one exchange: the command and the OUT each reply value belongs to."""

    @abstractmethod
    def barrier_commands(self) -> tuple[Command, ...]:
        """Harmless reads with distinct main commands, used to resynchronise after a lost reply."""


class LkG3001(LkgDialect):
    """LK-G3000 series controller: OUT1/OUT2, ``M0``/``M1``/``M2``."""

    def __init__(self) -> None:
        super().__init__("LK-G3001", max_out=2, out_width=1)

    def read_output(self, out: int) -> Command:
        main = f"M{self.out_field(out)}"
        return Command(main, main, main, "values", 1)

    def read_outputs(self, outs: tuple[int, ...]) -> tuple[Command, tuple[int, ...]]:
        for o in outs:
            self.check_out(o)
        if len(outs) == 1:
            return self.read_output(outs[0]), outs
        return Command("M0", "M0", "M0", "values", 2), (1, 2)

    def barrier_commands(self) -> tuple[Command, ...]:
        return (Command("M0", "M0", "M0", "values", 2), self.read_output(1), self.read_output(2))


class LkG5001(LkgDialect):
    """LK-G5000 series controller: OUT01..OUT12, ``MS``/``MM``/``MA``."""

    def __init__(self) -> None:
        super().__init__("LK-G5001", max_out=12, out_width=2)

    def read_output(self, out: int) -> Command:
        text = f"MS,{self.out_field(out)}"
        return Command(text, "MS", text, "values", 1)

    def read_outputs(self, outs: tuple[int, ...]) -> tuple[Command, tuple[int, ...]]:
        for o in outs:
            self.check_out(o)
        if not outs:
            raise ValueError("read_outputs needs at least one OUT")
        selected = tuple(sorted(set(outs)))
        mask = "".join("1" if o in selected else "0" for o in range(1, self.max_out + 1))
        text = f"MM,{mask}"
        return Command(text, "MM", text, "values", len(selected)), selected

    def read_all(self) -> Command:
        """``MA``: every OUT the controller has in use."""
        return Command("MA", "MA", "MA", "values", None)

    def barrier_commands(self) -> tuple[Command, ...]:
        mask = "1" + "0" * (self.max_out - 1)
        return (self.read_all(), Command(f"MM,{mask}", "MM", f"MM,{mask}", "values", 1), self.read_output(1))


def dialect_for(name: str) -> LkgDialect:
    """The dialect object for a controller model name ("LK-G3001" or "LK-G5001")."""
    if name == "LK-G3001":
        return LkG3001()
    if name == "LK-G5001":
        return LkG5001()
    raise ValueError(f"controller dialect {name!r} is not 'LK-G3001' or 'LK-G5001'; it is never guessed: set it in the config")
