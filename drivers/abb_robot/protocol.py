"""The line protocol between cellctl and the RAPID server module (``rapid/CellctlServer.mod``).

This module is the one source of truth for the protocol: the Python client and the fake
controller both encode and decode through it, the table in ``README.md`` is generated from it
(``python -m abb_robot.protocol_table``), and a test checks that the RAPID module names the same
verbs, error codes and version.

Framing: ASCII lines ended by ``"\\n"``; a line, terminator included, is at most
:data:`MAX_LINE` (80) bytes, the longest string RAPID can hold. A request is
``<id> <VERB> [args...]`` with ``id`` an integer in 1..99999 chosen by the client; every reply
line starts with the same id and a status word:

- ``ACK``: a motion or EGM session was accepted and started;
- ``DATA``: one part of a multi-line answer (more lines follow);
- ``OK``: the final answer to a query or setting, with its data;
- ``DONE``: the motion or EGM session acknowledged earlier has finished as asked;
- ``ERR <code> <text>``: refused or failed (see :class:`ErrorCode`);
- ``PONG``: the answer to ``PING``.

Units on the wire: mm, degrees, quaternions w x y z (ABB's q1..q4). Positions are written with
3 decimals, quaternions with 7 decimals by the client and 6 by the controller (RAPID's ``num`` is
a single-precision float), joint angles with 4 decimals.
"""

from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass
from typing import Literal, Sequence

PROTOCOL_VERSION = 1
MAX_LINE = 80
"""Longest line in bytes, the terminating newline included (RAPID strings hold 80 characters)."""
MAX_REQUEST_ID = 99999
MAX_ABS_POSITION_MM = 99999.0
NAME_PATTERN = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,31}$")
"""A RAPID identifier (tool and work object names)."""

POSITION_DECIMALS = 3
CLIENT_QUATERNION_DECIMALS = 7
SERVER_QUATERNION_DECIMALS = 6
JOINT_DECIMALS = 4
QUATERNION_NORM_TOLERANCE = 1e-5


class ErrorCode(enum.IntEnum):
    """Error codes of ``ERR`` replies. The RAPID module defines the same numbers."""

    SYNTAX = 100
    TOO_LONG = 101
    VERSION = 102
    NO_HELLO = 103
    BUSY = 110
    NO_TARGET = 111
    SEQUENCE = 112
    UNKNOWN_TOOL = 120
    UNKNOWN_WOBJ = 121
    RANGE = 122
    REACH = 130
    JOINT_LIMIT = 131
    STOPPED = 140
    MOTION = 141
    EGM_COMM = 150
    EGM_SETUP = 151
    EGM_STATE = 152
    GRIPPER = 160
    INTERNAL = 199


ERROR_DESCRIPTIONS: dict[ErrorCode, str] = {
    ErrorCode.SYNTAX: "malformed line, unknown verb or bad argument",
    ErrorCode.TOO_LONG: "line longer than 80 bytes (reply id 0); the rest up to the newline is dropped",
    ErrorCode.VERSION: "the client's protocol version is not the server's",
    ErrorCode.NO_HELLO: "a request before the HELLO handshake",
    ErrorCode.BUSY: "a motion or EGM session is running; settings and motions must wait (EGM also while a position stream runs)",
    ErrorCode.NO_TARGET: "MOVEL/MOVEJ without a staged POS and ORI",
    ErrorCode.SEQUENCE: "ORI without a POS before it",
    ErrorCode.UNKNOWN_TOOL: "no tooldata of that name in the motion task",
    ErrorCode.UNKNOWN_WOBJ: "no wobjdata of that name in the motion task",
    ErrorCode.RANGE: "a value out of its range (speed, zone, quaternion norm, EGM band)",
    ErrorCode.REACH: "target outside the robot's reach (CalcJointT: ERR_OUTSIDE_REACH)",
    ErrorCode.JOINT_LIMIT: "target needs an axis beyond its limit (CalcJointT: ERR_ROBLIMIT)",
    ErrorCode.STOPPED: "the motion or EGM session was stopped (STOP, or the link was lost)",
    ErrorCode.MOTION: "the motion failed on the controller",
    ErrorCode.EGM_COMM: "EGM session ended: no data from the sensor within CommTimeout (ERR_UDPUC_COMM, elog 41822)",
    ErrorCode.EGM_SETUP: "EGM could not be set up for a session or a position stream (UdpUc device or ExtMotionData profile)",
    ErrorCode.EGM_STATE: "EGM session ended on an EGM error (reference out of bounds, supervision)",
    ErrorCode.GRIPPER: "the gripper output could not be set (no signal of the configured name, or an I/O error)",
    ErrorCode.INTERNAL: "unexpected error in the server module",
}


class Status(enum.Enum):
    """The status word of a reply line."""

    ACK = "ACK"
    DATA = "DATA"
    OK = "OK"
    DONE = "DONE"
    ERR = "ERR"
    PONG = "PONG"


TERMINAL = frozenset({Status.OK, Status.DONE, Status.ERR, Status.PONG})
"""A line with one of these ends the answer to a request (ACK is followed by DONE or ERR)."""

ArgKind = Literal["int", "num", "name"]
VerbKind = Literal["session", "setting", "staging", "motion", "query", "io", "stream"]


@dataclass(frozen=True)
class Arg:
    """One request argument: its name (with unit) and how it is parsed."""

    name: str
    kind: ArgKind


@dataclass(frozen=True)
class Verb:
    """One request verb.

    Attributes:
        name: the verb as it appears on the wire.
        args: its arguments in order.
        kind: session, setting, staging, motion, query, io (switches an output of the cell) or stream
            (the robot's position feedback over EGM).
        reply: the reply lines, in the README's notation.
        doc: what it does.
        while_moving: whether it is accepted while a motion or EGM session runs.
    """

    name: str
    args: tuple[Arg, ...]
    kind: VerbKind
    reply: str
    doc: str
    while_moving: bool


VERBS: dict[str, Verb] = {
    v.name: v
    for v in (
        Verb("HELLO", (Arg("version", "int"),), "session", "OK version robot_type rw_version",
             "handshake; must come first on every connection; clears staged POS/ORI", True),
        Verb("PING", (), "session", "PONG", "heartbeat", True),
        Verb("BYE", (), "session", "OK", "the server answers, closes the connection and listens again", True),
        Verb("TOOL", (Arg("name", "name"),), "setting", "OK name",
             "select the tooldata of that name in the motion task", False),
        Verb("WOBJ", (Arg("name", "name"),), "setting", "OK name",
             "select the wobjdata of that name in the motion task", False),
        Verb("SPEED", (Arg("v_tcp_mm_s", "num"), Arg("v_ori_deg_s", "num")), "setting", "OK v_tcp v_ori",
             "TCP and reorientation speed of the next motions", False),
        Verb("ZONE", (Arg("zone_mm", "num"),), "setting", "OK zone_mm",
             "zone of the next motions; 0 means fine (stop point)", False),
        Verb("POS", (Arg("x_mm", "num"), Arg("y_mm", "num"), Arg("z_mm", "num")), "staging", "OK",
             "stage the target position (current tool and work object); clears a staged ORI", True),
        Verb("ORI", (Arg("q1", "num"), Arg("q2", "num"), Arg("q3", "num"), Arg("q4", "num")), "staging", "OK",
             "stage the target orientation (quaternion w x y z, unit norm)", True),
        Verb("MOVEL", (), "motion", "ACK, then DONE or ERR",
             "linear move to the staged target; the target is consumed", False),
        Verb("MOVEJ", (), "motion", "ACK, then DONE or ERR",
             "joint move to the staged target; the target is consumed", False),
        Verb("EGM", (Arg("band_mm", "num"), Arg("band_deg", "num"), Arg("cond_s", "num")), "motion",
             "ACK, then DONE or ERR",
             "run an EGM pose session (EGMRunPose) until every axis stays within the band for cond_s (> 0)",
             False),
        Verb("STOP", (), "query", "OK was_moving",
             "stop the running motion or EGM session (it then ends with ERR 140) and end a position stream; "
             "was_moving: 1 if a motion or EGM session ran", True),
        Verb("GETC", (), "query", "DATA POS x y z; OK ORI q1 q2 q3 q4",
             "current TCP pose in the current tool and work object", True),
        Verb("GETJ", (), "query", "OK j1 j2 j3 j4 j5 j6", "current joint angles in degrees", True),
        Verb("STATE", (), "query", "OK motors moving",
             "motors: 1 on, 0 off, -1 unknown (signal not configured); moving: 1 while a motion runs", True),
        Verb("GRIP", (Arg("hold", "int"),), "io", "OK hold",
             "gripper vacuum: 1 on (hold the glass), 0 off (release it); sets the gripper output, waits its "
             "settle time, then answers; refused while moving, so the glass is never released mid-motion", False),
        Verb("STREAM", (Arg("on", "int"),), "stream", "OK on",
             "EGM position stream: 1 starts it (EGMStreamStart: an EgmRobot with the TCP pose in the current tool "
             "and work object every 4 ms to the EGM device's remote port; the sensor sends nothing back; "
             "a running stream restarts at seqno 0), 0 stops it; moves run while it streams; STOP, BYE and a "
             "lost link end it; refused while moving (start it before the moves, stop it after them); EGM, TOOL "
             "and WOBJ are refused while it streams (its frame was fixed at STREAM 1)", False),
    )
}

GRIP_VALUES = (0, 1)
"""``GRIP`` takes 1 (vacuum on, hold) or 0 (vacuum off, release); other integers are ``ERR 122``."""
STREAM_VALUES = (0, 1)
"""``STREAM`` takes 1 (start the position stream) or 0 (stop it); other integers are ``ERR 122``."""
STREAM_SAMPLE_MS = 4
"""The position stream's sample rate (``EGMStreamStart \\SampleRate``, ms; the module's CELLCTL_EGM_STREAM_RATE)."""


class ProtocolError(ValueError):
    """A line that does not follow the protocol.

    Attributes:
        code: the error code a server answers with.
        req_id: the request id, when it could be read (0 otherwise).
    """

    def __init__(self, message: str, code: ErrorCode = ErrorCode.SYNTAX, req_id: int = 0) -> None:
        super().__init__(message)
        self.code = code
        self.req_id = req_id


# ---------------------------------------------------------------------------------------------
# Numbers


def format_num(value: float, decimals: int) -> str:
    """A number as the protocol writes it: fixed decimals, no exponent, no ``-0``."""
    if not math.isfinite(value):
        raise ProtocolError(f"cannot send a non-finite number ({value!r})", ErrorCode.RANGE)
    text = f"{value:.{decimals}f}"
    if text.startswith("-") and float(text) == 0.0:
        text = text[1:]
    return text


_NUMBER = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)$")


def parse_num(token: str, what: str) -> float:
    """A decimal number without exponent (what RAPID's StrToVal reads and NumToStr writes)."""
    if not _NUMBER.match(token):
        raise ProtocolError(f"{what}: {token!r} is not a decimal number")
    return float(token)


def parse_int(token: str, what: str) -> int:
    if not re.fullmatch(r"[+-]?\d+", token):
        raise ProtocolError(f"{what}: {token!r} is not an integer")
    return int(token)


def check_name(name: str, what: str) -> str:
    if not NAME_PATTERN.match(name):
        raise ProtocolError(
            f"{what} {name!r} is not a RAPID name (a letter, then up to 31 letters, digits or '_')", ErrorCode.RANGE
        )
    return name


def normalised_quaternion(q: Sequence[float]) -> tuple[float, float, float, float]:
    """The unit quaternion (w, x, y, z); refuses a zero or non-finite one."""
    if len(q) != 4 or not all(math.isfinite(c) for c in q):
        raise ProtocolError(f"quaternion must be 4 finite numbers (w, x, y, z), got {tuple(q)!r}", ErrorCode.RANGE)
    n = math.sqrt(sum(c * c for c in q))
    if n < 1e-9:
        raise ProtocolError("quaternion has zero length", ErrorCode.RANGE)
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


# ---------------------------------------------------------------------------------------------
# Lines


def _encode(line: str) -> bytes:
    data = (line + "\n").encode("ascii")
    if len(data) > MAX_LINE:
        raise ProtocolError(f"line of {len(data)} bytes exceeds the {MAX_LINE}-byte limit: {line!r}", ErrorCode.TOO_LONG)
    return data


def decode_line(raw: bytes) -> str:
    """One received line (with or without its newline) as text; refuses overlong or non-ASCII."""
    if len(raw) > MAX_LINE:
        raise ProtocolError(f"line of {len(raw)} bytes exceeds the {MAX_LINE}-byte limit", ErrorCode.TOO_LONG)
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError(f"line is not ASCII: {raw[:40]!r}") from None
    return strip_line(text)


def split_fields(line: str) -> list[str]:
    """Fields of a line: separated by one or more spaces (only spaces, as the RAPID module splits)."""
    return [t for t in line.split(" ") if t]


def strip_line(text: str) -> str:
    """A received line without its newline and one trailing carriage return."""
    text = text[:-1] if text.endswith("\n") else text
    return text[:-1] if text.endswith("\r") else text


@dataclass(frozen=True)
class Request:
    """A parsed request line. ``args`` holds ints, floats or names per the verb's :class:`Arg` kinds."""

    req_id: int
    verb: str
    args: tuple[int | float | str, ...]


def check_request_id(req_id: int) -> int:
    if not (1 <= req_id <= MAX_REQUEST_ID):
        raise ProtocolError(f"request id {req_id} outside 1..{MAX_REQUEST_ID}")
    return req_id


def format_request(req_id: int, verb: str, *args: int | float | str) -> bytes:
    """Encode a request; checks the verb, its arguments and the line length."""
    check_request_id(req_id)
    spec = VERBS.get(verb)
    if spec is None:
        raise ProtocolError(f"unknown verb {verb!r}")
    if len(args) != len(spec.args):
        raise ProtocolError(f"{verb} takes {len(spec.args)} argument(s), got {len(args)}")
    parts = [str(req_id), verb]
    for arg, value in zip(spec.args, args):
        if arg.kind == "name":
            parts.append(check_name(str(value), arg.name))
        elif arg.kind == "int":
            parts.append(str(int(value)))
        else:
            decimals = CLIENT_QUATERNION_DECIMALS if verb == "ORI" else POSITION_DECIMALS
            if verb == "POS" and abs(float(value)) > MAX_ABS_POSITION_MM:
                raise ProtocolError(f"{arg.name} = {value} mm is beyond +-{MAX_ABS_POSITION_MM:g} mm", ErrorCode.RANGE)
            parts.append(format_num(float(value), decimals))
    return _encode(" ".join(parts))


def parse_request(line: str) -> Request:
    """Decode a request line (without newline). Raises :class:`ProtocolError` with the code to answer."""
    tokens = split_fields(line)
    if not tokens:
        raise ProtocolError("empty line")
    if not re.fullmatch(r"\d{1,5}", tokens[0]) or not (1 <= int(tokens[0]) <= MAX_REQUEST_ID):
        raise ProtocolError("line does not start with a request id")
    req_id = int(tokens[0])
    if len(tokens) < 2:
        raise ProtocolError("request id without a verb", req_id=req_id)
    verb = tokens[1].upper()
    spec = VERBS.get(verb)
    if spec is None:
        raise ProtocolError(f"unknown verb {tokens[1][:12]}", req_id=req_id)
    raw_args = tokens[2:]
    if len(raw_args) != len(spec.args):
        raise ProtocolError(f"{verb} takes {len(spec.args)} args, got {len(raw_args)}", req_id=req_id)
    values: list[int | float | str] = []
    for i, (arg, token) in enumerate(zip(spec.args, raw_args), start=1):
        # The messages are the RAPID module's, word for word.
        if arg.kind == "name":
            if not NAME_PATTERN.match(token):
                raise ProtocolError(f"{token[:32]} is not a RAPID name", ErrorCode.RANGE, req_id)
            values.append(token)
            continue
        if not _NUMBER.match(token):
            raise ProtocolError(f"argument {i} is not a decimal number", ErrorCode.SYNTAX, req_id)
        if arg.kind == "int":
            if not re.fullmatch(r"[+-]?\d+", token):
                raise ProtocolError(f"{arg.name} is not an integer", ErrorCode.SYNTAX, req_id)
            values.append(int(token))
        else:
            values.append(float(token))
    return Request(req_id, verb, tuple(values))


@dataclass(frozen=True)
class Reply:
    """A parsed reply line: the echoed id, the status and the remaining fields (text)."""

    req_id: int
    status: Status
    fields: tuple[str, ...]

    @property
    def error_code(self) -> int | None:
        """For ERR: the numeric code."""
        if self.status is not Status.ERR or not self.fields:
            return None
        return int(self.fields[0])

    @property
    def error_text(self) -> str:
        return " ".join(self.fields[1:]) if self.status is Status.ERR else ""


def format_reply(req_id: int, status: Status, *fields: str) -> bytes:
    """Encode a reply line. ERR text is cut so the line fits :data:`MAX_LINE`."""
    line = " ".join([str(req_id), status.value, *fields])
    if status is Status.ERR and len(line) + 1 > MAX_LINE:
        line = line[: MAX_LINE - 1].rstrip()
    return _encode(line)


def format_error(req_id: int, code: ErrorCode, text: str) -> bytes:
    """Encode ``<id> ERR <code> <text>`` (text cut to fit)."""
    clean = " ".join(split_fields(text)).encode("ascii", "replace").decode("ascii")
    return format_reply(req_id, Status.ERR, str(int(code)), clean)


def parse_reply(line: str) -> Reply:
    """Decode a reply line (without newline); :class:`ProtocolError` if it is not one."""
    tokens = split_fields(line)
    if len(tokens) < 2:
        raise ProtocolError(f"reply too short: {line[:40]!r}")
    try:
        req_id = parse_int(tokens[0], "reply id")
    except ProtocolError:
        raise ProtocolError(f"reply does not start with a request id: {line[:40]!r}") from None
    if not (0 <= req_id <= MAX_REQUEST_ID):
        raise ProtocolError(f"reply id {req_id} outside 0..{MAX_REQUEST_ID}")
    try:
        status = Status(tokens[1])
    except ValueError:
        raise ProtocolError(f"unknown reply status {tokens[1][:12]!r} in {line[:40]!r}", req_id=req_id) from None
    fields = tuple(tokens[2:])
    if status is Status.ERR:
        if not fields or not re.fullmatch(r"\d{3}", fields[0]):
            raise ProtocolError(f"ERR reply without a 3-digit code: {line[:40]!r}", req_id=req_id)
    return Reply(req_id, status, fields)


# ---------------------------------------------------------------------------------------------
# Reply payloads


def format_position_fields(xyz: Sequence[float]) -> tuple[str, str, str]:
    return tuple(format_num(float(v), POSITION_DECIMALS) for v in xyz)  # type: ignore[return-value]


def format_quaternion_fields(q: Sequence[float], decimals: int = SERVER_QUATERNION_DECIMALS) -> tuple[str, ...]:
    return tuple(format_num(float(v), decimals) for v in normalised_quaternion(q))


def parse_numbers(fields: Sequence[str], count: int, what: str) -> tuple[float, ...]:
    """Exactly ``count`` decimal numbers."""
    if len(fields) != count:
        raise ProtocolError(f"{what}: expected {count} numbers, got {len(fields)}: {' '.join(fields)[:40]!r}")
    return tuple(parse_num(f, what) for f in fields)


def parse_labelled(fields: Sequence[str], label: str, count: int) -> tuple[float, ...]:
    """``LABEL n1 .. n<count>`` as in ``DATA POS x y z`` and ``OK ORI q1 q2 q3 q4``."""
    if not fields or fields[0] != label:
        raise ProtocolError(f"expected {label} and {count} numbers, got {' '.join(fields)[:40]!r}")
    return parse_numbers(fields[1:], count, label)


# ---------------------------------------------------------------------------------------------
# Documentation


def markdown_tables() -> str:
    """The verb and error tables of README.md, generated from :data:`VERBS` and :class:`ErrorCode`."""
    lines = [
        f"Protocol version {PROTOCOL_VERSION}; every line at most {MAX_LINE} bytes including its newline.",
        "",
        "| Request | Kind | While moving | Reply | Meaning |",
        "|---|---|---|---|---|",
    ]
    for v in VERBS.values():
        req = " ".join(["id", v.name, *(a.name for a in v.args)])
        lines.append(f"| `{req}` | {v.kind} | {'yes' if v.while_moving else 'BUSY'} | `{v.reply}` | {v.doc} |")
    lines += ["", "| Code | Name | Meaning |", "|---|---|---|"]
    for code in ErrorCode:
        lines.append(f"| {int(code)} | {code.name} | {ERROR_DESCRIPTIONS[code]} |")
    return "\n".join(lines) + "\n"


TABLE_BEGIN = "<!-- protocol-table:begin (generated by python -m abb_robot.protocol_table) -->"
TABLE_END = "<!-- protocol-table:end -->"


def main() -> None:
    """Print the protocol tables (paste between the README markers)."""
    print(TABLE_BEGIN)
    print(markdown_tables(), end="")
    print(TABLE_END)
