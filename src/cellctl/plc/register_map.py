"""The line PLC's Modbus register map, defined once.

Every holding register the PLC can see is declared here with its address, type, writer, units and
meaning. The server builds its datastore from these blocks, the codec packs values by them, and
``docs/plc_register_map.md`` is rendered from them (``python -m cellctl.plc --write PATH``).

Addresses are 0-based protocol addresses of holding registers (FC3 read, FC6/FC16 write), so
address 0 is "40001" in Modicon notation. Each direction has its own block with a single writer:
the PLC writes only the PLC block, the cell only the cell block. Addresses never move: a new
register takes a reserved address and bumps ``MAP_VERSION``'s minor number; a change to an existing
register bumps the major number.
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass

from cellctl.domain import CycleStep, PackMLCommand, PackMLState, UnitMode

MAP_VERSION: tuple[int, int] = (1, 6)
"""(major, minor), published in the cell block so the PLC can check it talks to the map it expects.
1.1: refusal codes 905-907 (an unknown recipe or a cell not in Execute no longer answer 1501), refusals
stored under their cycle_req_id, exception 11 for another unit id; no register moved.
1.2: the inspection's measured result (inspection_status, meas_* at 137-149); no register moved.
1.3: refusal code 908, a recipe of the cell not taught yet; no register moved.
1.4: ``cmd_result`` 5 (blocked): a command the state model allows but an interlock holds back, told
apart from 1 (not allowed in this state); no register moved.
1.5: ``car_body_id`` (11-12) and its echo ``result_car_body_id`` (150-151); ``cycle_flags`` bits 8
``install_started`` and 9 ``robot_clear``; a new ``cycle_req_id`` written while ``cycle_request`` stays 1 is
served after the running cycle (it was never answered); no register moved.
1.6: ``interlock_alarm_id`` (152), the alarm behind ``cmd_result`` 5 (blocked); no register moved."""

PLC_ERROR_CODE_RANGE = range(900, 1000)
"""Error codes raised by the PLC interface itself (see ``PlcErrorCode``), reserved in the cell's
alarm / stop-reason id space."""


class CommandReply(enum.IntEnum):
    """How the cell answered a PackML command or unit mode request (``cmd_result`` on the wire)."""

    ACCEPTED = 0
    INVALID_IN_STATE = 1
    BUSY = 2
    BAD_PARAMETER = 3
    NO_ANSWER = 4
    BLOCKED = 5


COMMAND_REPLY_TEXT: dict[CommandReply, str] = {
    CommandReply.ACCEPTED: "Accepted: the command (or mode change) was carried out (a Stop in Stopped while a "
                           "commissioning job runs cancels the job; the cell stays Stopped).",
    CommandReply.INVALID_IN_STATE: "Refused: the PackML state model does not allow this command in the current "
                                   "state (a unit mode request: not in this state; see Start-up and states). Send "
                                   "a command the state allows.",
    CommandReply.BUSY: "Not sent by this cell (reserved).",
    CommandReply.BAD_PARAMETER: "Refused: `cntrl_cmd` or `unit_mode_request` is not a valid value.",
    CommandReply.NO_ANSWER: "The cell's controller did not answer within facade_timeout_s (or failed); send "
                            "the request again.",
    CommandReply.BLOCKED: "Refused by an interlock: the state model allows the command, but the cell holds "
                          "it back now (an active alarm with a reaction, Complete while a cycle runs, Start "
                          "while a commissioning job runs); the cell's log names it. Remove the cause "
                          "(acknowledge the alarm, clear its cause, wait for the cycle), then send it again.",
}
"""What each ``cmd_result`` / ``unit_mode_result`` code means, for the generated docs."""


class PlcErrorCode(enum.IntEnum):
    """Error codes raised by the PLC interface itself, within ``PLC_ERROR_CODE_RANGE``.

    901-904 say the interface could not get a definite answer; 905-908 are the cell's refusals of a
    request it will never run (stored under the request's ``cycle_req_id``, see ``STORED_REFUSALS``).
    """

    CYCLE_REQ_ID_ZERO = 901
    CELL_NO_ANSWER = 902
    RESULT_TIMEOUT = 903
    CELL_BAD_ANSWER = 904
    UNKNOWN_RECIPE = 905
    NOT_READY = 906
    ID_IN_USE = 907
    RECIPE_NOT_TAUGHT = 908


UNIT_ID_EXCEPTION = 11
"""The Modbus exception code (gateway target device failed to respond) a request to another unit id
than ``[plc] unit_id`` gets."""

STORED_REFUSALS: frozenset[PlcErrorCode] = frozenset(
    {PlcErrorCode.UNKNOWN_RECIPE, PlcErrorCode.NOT_READY, PlcErrorCode.ID_IN_USE, PlcErrorCode.RECIPE_NOT_TAUGHT})
"""Refusals stored as the result of their ``cycle_req_id``: a repeated id republishes them with
``replayed`` = 1 (like any refusal by the cell). The other codes are not results: repeating the id
asks the cell again."""

PLC_ERROR_TEXT: dict[PlcErrorCode, str] = {
    PlcErrorCode.CYCLE_REQ_ID_ZERO: "cycle_request = 1 with cycle_req_id = 0: give each cycle a nonzero id.",
    PlcErrorCode.CELL_NO_ANSWER: "The cell's controller did not answer within facade_timeout_s (or failed); "
                                 "request the same id again to ask again (the cell never runs an id twice).",
    PlcErrorCode.RESULT_TIMEOUT: "An accepted cycle gave no result within cycle_result_timeout_s; "
                                 "requesting the same id again waits for it again (it never runs twice).",
    PlcErrorCode.CELL_BAD_ANSWER: "The cell's controller answered with something the map cannot carry "
                                  "(another id's result, a value out of range).",
    PlcErrorCode.UNKNOWN_RECIPE: "Refused: recipe_id is not one of the cell's recipe numbers (see Recipes). "
                                 "Nothing ran; send the request again with a valid recipe_id and a new id.",
    PlcErrorCode.NOT_READY: "Refused: the cell did not take a cycle then; it takes one only in Execute and "
                            "not in Manual mode (state_current = 6, `ready` = 1) and the cell's log says why. "
                            "Nothing ran; bring the cell to Execute (Clear, Reset, Start as the state asks; in "
                            "Manual, switch to Production first) and request again with a new id.",
    PlcErrorCode.ID_IN_USE: "Refused: the cell's store holds this cycle_req_id for another request it could "
                            "not match. Nothing ran; use a new id.",
    PlcErrorCode.RECIPE_NOT_TAUGHT: "Refused: the recipe is one of the cell's but is not taught yet, or its teaching "
                                    "or nine-point map is not ready (stale, expired; `cellctl calibrate status` names "
                                    "the command: `cellctl teach --recipe NAME`, then its nine-point map). Nothing "
                                    "ran; request another recipe, or this one with a new id once it is ready.",
}


class RegType(enum.Enum):
    """Wire type of a register: its name and how many 16-bit words it takes."""

    UINT16 = ("uint16", 1)
    INT16 = ("int16", 1)
    UINT32 = ("uint32", 2)
    FLOAT32 = ("float32", 2)

    @property
    def label(self) -> str:
        return self.value[0]

    @property
    def words(self) -> int:
        return self.value[1]


class Access(enum.Enum):
    """Which side writes a register (the other side only reads it)."""

    PLC_WRITES = "PLC"
    CELL_WRITES = "cell"


@dataclass(frozen=True)
class Bit:
    """One named bit of a flags word (bit 0 is the least significant)."""

    index: int
    name: str
    description: str


@dataclass(frozen=True)
class Register:
    """One value in the map; 32-bit types take ``address`` and ``address + 1``."""

    name: str
    address: int
    type: RegType
    access: Access
    units: str
    description: str
    bits: tuple[Bit, ...] = ()

    @property
    def words(self) -> int:
        return self.type.words

    @property
    def end(self) -> int:
        """One past the last word."""
        return self.address + self.type.words


@dataclass(frozen=True)
class Block:
    """A contiguous address range with one writer; unmapped addresses inside it are reserved (the cell
    block's read 0; the PLC block's keep what a client writes there and the cell never reads them)."""

    name: str
    access: Access
    start: int
    size: int
    registers: tuple[Register, ...]

    @property
    def end(self) -> int:
        return self.start + self.size

    def contains(self, address: int) -> bool:
        return self.start <= address < self.end

    def overlaps(self, address: int, count: int) -> bool:
        return address < self.end and self.start < address + count

    def register(self, name: str) -> Register:
        for reg in self.registers:
            if reg.name == name:
                return reg
        known = ", ".join(r.name for r in self.registers)
        raise KeyError(f"no register {name!r} in the {self.name}; it has: {known}")


def _enum_list(enum_cls: type[enum.IntEnum]) -> str:
    return ", ".join(f"{m.value} {m.name.lower()}" for m in enum_cls)


_P = Access.PLC_WRITES
_C = Access.CELL_WRITES
_U16, _I16, _U32, _F32 = RegType.UINT16, RegType.INT16, RegType.UINT32, RegType.FLOAT32

CYCLE_FLAG_BITS: tuple[Bit, ...] = (
    Bit(0, "ready", "The cell would accept a cycle request now: 1 only in Execute (`state_current` = 6) in "
        "Production or Maintenance (not Manual), while no request is being served and `cycle_request` = 0; "
        "0 otherwise."),
    Bit(1, "busy", "A cycle for `cycle_ack_id` is running."),
    Bit(2, "done", "The result registers hold the result of `cycle_ack_id`; stays on until the "
        "PLC drops `cycle_request` (or writes another `cycle_req_id`, the next request)."),
    Bit(3, "ok", "With done: the cycle succeeded (`error_code` = 0)."),
    Bit(4, "nok", "With done: the cycle failed or was refused; `error_code` says why."),
    Bit(5, "replayed", "With done: `cycle_req_id` was seen before; its stored result (a cycle's "
        "result or a refusal) was published again and no new cycle ran."),
    Bit(6, "plc_heartbeat_ok", "The cell sees `plc_heartbeat` change within the configured timeout."),
    Bit(7, "request_mismatch", "With replayed: the repeated id came with a part, recipe or car body other "
        "than the stored result's (the stored result stands)."),
    Bit(8, "install_started", "With done: the cycle had started to install its glass (the robot was "
        "commanded into the opening). With `nok` this means a glass may be in the opening or half in it: "
        "check the car body before it moves on. 0 with `nok`: the glass never left the cell's side "
        "(refused, or stopped before the install)."),
    Bit(9, "robot_clear", "The line may move the car body: no cycle runs and the robot's flange stands at "
        "least `[plc] clear_distance_mm` in front of the car body's wall (its reported pose against the "
        "wall plane the last cycle fitted). 0 while a cycle runs or waits, after a cycle that did not end "
        "done (failed, stopped, aborted; the cell then does not know where that car body's wall is), and "
        "whenever the robot's pose is unknown. Refreshed a few times a second: after `done` it comes "
        "within about a second."),
)

PLC_BLOCK = Block(
    name="PLC block",
    access=_P,
    start=0,
    size=32,
    registers=(
        Register("plc_heartbeat", 0, _U16, _P, "count",
                 "Change it (increment or toggle) at least every heartbeat_timeout_s / 5; "
                 "unchanged for heartbeat_timeout_s means PLC heartbeat lost."),
        Register("cntrl_cmd", 1, _U16, _P, "PackMLCommand",
                 f"PackML Command.CntrlCmd: {_enum_list(PackMLCommand)}. Latched by cmd_change_request."),
        Register("cmd_change_request", 2, _U16, _P, "0/1",
                 "Command.CmdChangeRequest: set to 1 to latch cntrl_cmd; keep it until cmd_ack = 1, "
                 "then set 0."),
        Register("unit_mode_request", 3, _U16, _P, "UnitMode",
                 f"Requested unit mode: {_enum_list(UnitMode)}. Latched by unit_mode_change_request; "
                 "taken only in the states of `[packml] mode_change_states` (see Start-up and states)."),
        Register("unit_mode_change_request", 4, _U16, _P, "0/1",
                 "Command.UnitModeChangeRequest: set to 1 to latch unit_mode_request; keep it until "
                 "unit_mode_ack = 1, then set 0."),
        Register("recipe_id", 5, _U16, _P, "id",
                 "Recipe (window type) of the requested cycle: an `id` of the config's "
                 "`[[process.recipes]]` (see Recipes)."),
        Register("part_id", 6, _U32, _P, "id", "Part (window) serial of the requested cycle."),
        Register("cycle_req_id", 8, _U32, _P, "id",
                 "Cycle request id, nonzero and new for each cycle (each car body): the idempotency key. A "
                 "repeated id never starts a second cycle; its stored result is published again. Another id "
                 "written while cycle_request stays 1 is the next request, served after the running one."),
        Register("cycle_request", 10, _U16, _P, "0/1",
                 "Set to 1 (with recipe_id, part_id, cycle_req_id and car_body_id in the same FC16 write) "
                 "to request a cycle; keep it until done = 1 for this id, read the result, then set 0."),
        Register("car_body_id", 11, _U32, _P, "id",
                 "Car body (vehicle) the glass of the requested cycle goes into; 0 = none given. The cycle "
                 "records it as its car id (decimal text, like part_id: REST `car_id`, GET /parts?car_id=, "
                 "OPC UA LastResult.CarId)."),
    ),
)

CELL_BLOCK = Block(
    name="cell block",
    access=_C,
    start=100,
    size=64,
    registers=(
        Register("map_version_major", 100, _U16, _C, "-",
                 "Register map major version: a change means existing registers moved or changed."),
        Register("map_version_minor", 101, _U16, _C, "-",
                 "Register map minor version: registers were added at reserved addresses."),
        Register("cell_heartbeat", 102, _U16, _C, "count",
                 "Incremented by the cell every cell_heartbeat_period_s (wraps at 65535); it stops "
                 "when the cell's controller does not answer."),
        Register("state_current", 103, _U16, _C, "PackMLState",
                 f"PackML Status.StateCurrent: {_enum_list(PackMLState)}."),
        Register("unit_mode_current", 104, _U16, _C, "UnitMode",
                 f"PackML Status.UnitModeCurrent: {_enum_list(UnitMode)}."),
        Register("cycle_step", 105, _U16, _C, "CycleStep",
                 f"Step of the running cycle (sub-state of Execute): {_enum_list(CycleStep)}."),
        Register("stop_reason_id", 106, _U16, _C, "id",
                 "First-out alarm / stop reason id; 0 when none is active."),
        Register("cycle_flags", 107, _U16, _C, "bits", "Cycle handshake flags (bits below).",
                 bits=CYCLE_FLAG_BITS),
        Register("cycle_ack_id", 108, _U32, _C, "id",
                 "Echo of cycle_req_id once the cell has taken the request (accepted, refused or "
                 "replayed)."),
        Register("result_req_id", 110, _U32, _C, "id",
                 "cycle_req_id the result registers belong to (they keep the last result after done "
                 "drops)."),
        Register("result_part_id", 112, _U32, _C, "id", "part_id of that result."),
        Register("result_recipe_id", 114, _U16, _C, "id",
                 "recipe_id of that result: the one the PLC requested its cycle with, kept with the cycle (a "
                 "later change of [[process.recipes]] ids or names does not change it; a cycle stored before the "
                 "cell kept it answers its recipe's id in the current configuration, 0 if none)."),
        Register("error_code", 115, _U16, _C, "id",
                 "0 when ok; else why the cycle failed or was refused: the cell's alarm / stop reason "
                 "id, or 900-999 for the PLC interface's own codes."),
        Register("dx_mm", 116, _F32, _C, "mm",
                 "Install correction along X of the workpiece frame (install pose minus taught "
                 "install pose)."),
        Register("dy_mm", 118, _F32, _C, "mm", "Install correction along Y of the workpiece frame."),
        Register("dz_mm", 120, _F32, _C, "mm", "Install correction along Z of the workpiece frame."),
        Register("drx_deg", 122, _F32, _C, "deg",
                 "Install correction about X (XYZ fixed angles, eq. 13 of the method)."),
        Register("dry_deg", 124, _F32, _C, "deg", "Install correction about Y."),
        Register("drz_deg", 126, _F32, _C, "deg", "Install correction about Z."),
        Register("cycle_time_ms", 128, _U32, _C, "ms",
                 "Duration of the cycle on the cell's clock, start to result (in simulation: the robot time a "
                 "real cell would take)."),
        Register("cmd_ack", 130, _U16, _C, "0/1",
                 "1 once the latched command was handled (cmd_result says how); 0 after the PLC "
                 "drops cmd_change_request."),
        Register("cmd_ack_cmd", 131, _U16, _C, "PackMLCommand", "Echo of the command that cmd_ack answers."),
        Register("cmd_result", 132, _U16, _C, "code",
                 f"{_enum_list(CommandReply)} (see Codes): 1 when the state model does not allow the "
                 "command now, 5 when an interlock holds it back."),
        Register("unit_mode_ack", 133, _U16, _C, "0/1",
                 "1 once the latched mode request was handled; 0 after the PLC drops "
                 "unit_mode_change_request."),
        Register("unit_mode_ack_mode", 134, _U16, _C, "UnitMode", "Echo of the mode that unit_mode_ack answers."),
        Register("unit_mode_result", 135, _U16, _C, "code", "Same codes as cmd_result."),
        Register("refused_write_count", 136, _U16, _C, "count",
                 "PLC writes into the cell block that were refused (exception 2), wrapping at 65535."),
        Register("inspection_status", 137, _U16, _C, "code",
                 "The installed glass as the cell measured it: 0 not measured (inspection off, or the "
                 "cycle failed before it), 1 within the tolerance, 2 outside it (the part is nok, "
                 "error_code 1311)."),
        Register("meas_dx_mm", 138, _F32, _C, "mm",
                 "Measured install deviation along X of the opening's frame (the glass's corner "
                 "against the opening's, from the gaps in the image); 0 when not measured."),
        Register("meas_dy_mm", 140, _F32, _C, "mm", "Measured install deviation along Y (from the gaps)."),
        Register("meas_dz_mm", 142, _F32, _C, "mm",
                 "Measured install deviation along Z: the glass's surface against the wall at the "
                 "corner (+ = recessed), from the laser's flush readings."),
        Register("meas_drx_deg", 144, _F32, _C, "deg", "Measured rotation about X (flush; XYZ fixed angles, eq. 13)."),
        Register("meas_dry_deg", 146, _F32, _C, "deg", "Measured rotation about Y (flush)."),
        Register("meas_drz_deg", 148, _F32, _C, "deg", "Measured rotation about Z (the gaps' angle)."),
        Register("result_car_body_id", 150, _U32, _C, "id",
                 "car_body_id of that result (0: none given)."),
        Register("interlock_alarm_id", 152, _U16, _C, "id",
                 "The first active alarm holding back Reset, Start, Unhold and Unsuspend (cmd_result 5, blocked); "
                 "0 when none. Unlike stop_reason_id it is set in any state, e.g. a laser lost while Idle."),
    ),
)

BLOCKS: tuple[Block, ...] = (PLC_BLOCK, CELL_BLOCK)
MAX_REGISTERS_PER_REQUEST = 123
"""FC16 writes at most 123 registers (FC3 reads 125): each block must fit one request."""

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


def check_map(blocks: tuple[Block, ...] = BLOCKS) -> None:
    """Refuse an inconsistent map: overlaps, registers outside their block or of the wrong writer."""
    names: set[str] = set()
    for i, block in enumerate(blocks):
        if block.size > MAX_REGISTERS_PER_REQUEST:
            raise ValueError(f"{block.name}: {block.size} registers do not fit one Modbus request "
                             f"(at most {MAX_REGISTERS_PER_REQUEST})")
        for other in blocks[i + 1:]:
            if block.overlaps(other.start, other.size):
                raise ValueError(f"{block.name} and {other.name} overlap")
        taken: dict[int, str] = {}
        for reg in block.registers:
            if not _NAME.match(reg.name):
                raise ValueError(f"register name {reg.name!r} must be snake_case")
            if reg.name in names:
                raise ValueError(f"register name {reg.name!r} is used twice")
            names.add(reg.name)
            if reg.access is not block.access:
                raise ValueError(f"{reg.name} is written by {reg.access.value} but sits in the "
                                 f"{block.name}, written by {block.access.value}")
            if not (block.start <= reg.address and reg.end <= block.end):
                raise ValueError(f"{reg.name} ({reg.address}..{reg.end - 1}) lies outside the "
                                 f"{block.name} ({block.start}..{block.end - 1})")
            for addr in range(reg.address, reg.end):
                if addr in taken:
                    raise ValueError(f"{reg.name} overlaps {taken[addr]} at address {addr}")
                taken[addr] = reg.name
            if reg.bits:
                if reg.type is not RegType.UINT16:
                    raise ValueError(f"{reg.name}: flag bits need a uint16 register")
                indices = [b.index for b in reg.bits]
                if len(set(indices)) != len(indices) or not all(0 <= k < 16 for k in indices):
                    raise ValueError(f"{reg.name}: bit indices must be unique and in 0..15")


check_map()
if set(COMMAND_REPLY_TEXT) != set(CommandReply):
    raise RuntimeError("every CommandReply needs a text in COMMAND_REPLY_TEXT")
if set(PLC_ERROR_TEXT) != set(PlcErrorCode) or not all(c in PLC_ERROR_CODE_RANGE for c in PlcErrorCode):
    raise RuntimeError("every PlcErrorCode needs a text in PLC_ERROR_TEXT and a value in PLC_ERROR_CODE_RANGE")
if not STORED_REFUSALS <= set(PlcErrorCode):
    raise RuntimeError("STORED_REFUSALS must name PlcErrorCode members")


def register(name: str) -> Register:
    """The register called ``name`` in either block."""
    for block in BLOCKS:
        for reg in block.registers:
            if reg.name == name:
                return reg
    raise KeyError(f"no register {name!r} in the PLC register map")
