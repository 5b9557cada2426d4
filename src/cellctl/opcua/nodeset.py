"""The cell's OPC UA address space, defined once: the server builds it and docs/opcua_nodeset.md is rendered from it.

It follows OPC 30050 (PackML) where it applies: under ``Objects/PackMLObjects`` the cell's object holds
``Status``, ``Admin`` and the nested state machines ``BaseStateMachine/MachineState/ExecuteState``, each
with ``CurrentState`` (text, ``Id`` and ``Number``, the PackTags state integers) and its command methods,
with the spec's browse names in the PackML namespace. The cell's own nodes (a flat ``StateCurrent``
integer for PLCs, the counters, the stop reason's fields, ``Cycle`` with ``StartCycle`` and the last
result, the alarm conditions) are in the cellctl namespace. Node ids are strings
``<cell_id>.<path with dots>`` in the cellctl namespace.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from cellctl.domain import DEVIATION_KEYS, PackMLCommand, PackMLState, UnitMode

PACKML_NS = "http://opcfoundation.org/UA/PackML/"
CELLCTL_NS = "urn:cellctl:opcua"
PACKML_VERSION = "1.01"

Namespace = Literal["packml", "cellctl"]
DataType = Literal["Boolean", "Int32", "UInt16", "UInt32", "Float", "Double", "String", "DateTime", "LocalizedText", "NodeId"]


@dataclass(frozen=True)
class Var:
    """A variable: ``path`` below the cell object, its type (``array``: a one-dimensional array), what it says."""

    path: str
    ns: Namespace
    type: DataType
    description: str
    array: bool = False
    property: bool = False  # a property (HasProperty) of its parent variable, e.g. CurrentState's Id and Number


@dataclass(frozen=True)
class Arg:
    name: str
    type: DataType
    description: str
    array: bool = False


@dataclass(frozen=True)
class Method:
    """A method below the cell object; ``command`` is the PackML command it issues, if it is one;
    ``read_only``: it changes nothing, so a viewer user may call it too."""

    path: str
    ns: Namespace
    description: str
    inputs: tuple[Arg, ...] = ()
    outputs: tuple[Arg, ...] = ()
    command: PackMLCommand | None = None
    read_only: bool = False


STATE_MACHINES = ("BaseStateMachine", "BaseStateMachine/MachineState", "BaseStateMachine/MachineState/ExecuteState")
"""The three nested state machines of OPC 30050, outermost first."""

RUNNING, CLEARED = 18, 19
"""OPC 30050's super-state numbers (the PackTags states are 1..17)."""

STATE_NAMES: dict[int, str] = {
    **{int(s): s.name.capitalize() for s in PackMLState if s is not PackMLState.UNDEFINED}, RUNNING: "Running", CLEARED: "Cleared",
}  # fmt: skip
"""Every state's number and name, as the States folder and CurrentState show them."""

_BASE = {PackMLState.ABORTING, PackMLState.ABORTED}
_MACHINE = {PackMLState.CLEARING, PackMLState.STOPPED, PackMLState.STOPPING}


def state_path(state: PackMLState) -> tuple[tuple[str, int], ...]:
    """(name, number) of the current state of each machine in :data:`STATE_MACHINES` (empty name: inactive).

    Aborting/Aborted are states of the base machine; Clearing/Stopped/Stopping of the machine state
    machine inside Cleared (19); the other twelve of the execute machine inside Running (18).
    """
    none = ("", 0)
    if state is PackMLState.UNDEFINED:
        return (none, none, none)
    name = (state.name.capitalize(), int(state))
    if state in _BASE:
        return (name, none, none)
    if state in _MACHINE:
        return (("Cleared", CLEARED), name, none)
    return (("Cleared", CLEARED), ("Running", RUNNING), name)


def _state_vars(machine: str) -> tuple[Var, ...]:
    return (
        Var(f"{machine}/CurrentState", "packml", "LocalizedText", "the machine's current state by name (empty while inactive)"),
        Var(f"{machine}/CurrentState/Id", "packml", "NodeId", "the current state's node (cellctl States folder)", property=True),
        Var(f"{machine}/CurrentState/Number", "packml", "UInt32", "the current state's number (PackTags; Running 18, Cleared 19)", property=True),
    )  # fmt: skip


RESULT_FIELDS: tuple[Var, ...] = (
    Var("Cycle/LastResult/CycleId", "cellctl", "UInt32",
        "the finished cycle's id (REST /cycles/{id}); written last, after the cycle's other LastResult fields: key on it"),
    Var("Cycle/LastResult/RequestId", "cellctl", "String", "the idempotency key it was started with (StartCycle's RequestId)"),
    Var("Cycle/LastResult/Recipe", "cellctl", "String", "recipe name"),
    Var("Cycle/LastResult/PartId", "cellctl", "String", "the glass's part id"),
    Var("Cycle/LastResult/CarId", "cellctl", "String", "the car body's id (empty if none was given)"),
    Var("Cycle/LastResult/Ok", "cellctl", "Boolean", "installed and measured within the tolerance"),
    Var("Cycle/LastResult/ErrorCode", "cellctl", "UInt16", "0 when Ok, else the alarm id (docs/alarm_reactions.md)"),
    Var("Cycle/LastResult/Reason", "cellctl", "String", "why it is not Ok (empty when Ok)"),
    Var("Cycle/LastResult/MeasuredDeviation", "cellctl", "Double", "measured install deviation [dx, dy, dz mm, drx, dry, drz deg] (empty if not measured)", array=True),
    *(Var(f"Cycle/LastResult/Measured/{k}", "cellctl", "Double",
          f"measured {k.replace('_', ' in ')}; status BadNoData (no value) when the cycle measured nothing") for k in DEVIATION_KEYS),
    Var("Cycle/LastResult/CycleTime", "cellctl", "Double", "cycle time in s on the cell's clock (simulation: robot time)"),
    Var("Cycle/LastResult/CalibrationVersion", "cellctl", "String", "calibration set version the cycle ran with"),
    Var("Cycle/LastResult/FinishedAt", "cellctl", "DateTime", "when the cycle finished (UTC)"),
)  # fmt: skip

VARIABLES: tuple[Var, ...] = (
    Var("TagID", "packml", "String", "the cell's id (config cell_id)"),
    Var("PackMLVersion", "packml", "String", f"PackML model version followed ({PACKML_VERSION})"),
    Var("Status/UnitModeCurrent", "packml", "Int32", "0 invalid, 1 production, 2 maintenance, 3 manual"),
    Var("Status/UnitSupportedModes", "packml", "Int32", "the unit modes SetUnitMode accepts", array=True),
    Var("Status/MachSpeed", "packml", "Float", "design speed in parts per minute (from the last cycle times)"),
    Var("Status/CurMachSpeed", "packml", "Float", "current speed in parts per minute (0 when not producing)"),
    Var("Status/EquipmentBlocked", "packml", "Boolean", "held by a downstream condition (always false: the cell has no downstream)"),
    Var("Status/EquipmentStarved", "packml", "Boolean", "in Execute and waiting for a cycle request"),
    Var("Status/StateCurrent", "cellctl", "Int32", "PackTags state integer (1 Clearing .. 17 Complete), as the Modbus register"),
    Var("Status/CycleStep", "cellctl", "Int32", "sub-step of Execute: 0 none, 1 calibrate, 2 align, 3 shoot, 4 compensate, 5 install, 6 inspect"),
    Var("Status/ReadyForCycle", "cellctl", "Boolean", "StartCycle would be accepted now"),
    Var("Admin/ProcessedCount", "cellctl", "Int32", "glasses whose install began since the service started, done or "
        "stopped after it began (ProdProcessedCount's Count)"),
    Var("Admin/DefectiveCount", "cellctl", "Int32", "of those, not ok: measured outside the tolerance, or stopped after the "
        "install began (ProdDefectiveCount's Count)"),
    Var("Admin/StopReason/ID", "cellctl", "Int32", "first-out alarm id, 0 when none (PackMLAlarmDataType.ID)"),
    Var("Admin/StopReason/Value", "cellctl", "Int32", "its sub-code (Value)"),
    Var("Admin/StopReason/Message", "cellctl", "String", "its text (Message)"),
    Var("Admin/StopReason/Category", "cellctl", "Int32", "its fault class (Category)"),
    Var("Admin/StopReason/DateTime", "cellctl", "DateTime", "when it was raised (DateTime)"),
    Var("Admin/StopReason/AckDateTime", "cellctl", "DateTime", "when it was acknowledged (AckDateTime)"),
    Var("Admin/StopReason/Trigger", "cellctl", "Boolean", "still active (Trigger)"),
    *(v for m in STATE_MACHINES for v in _state_vars(m)),
    Var("Cycle/LastRefusal", "cellctl", "String", "why the last StartCycle or command was refused (with its time)"),
    *RESULT_FIELDS,
)  # fmt: skip

_EXEC = "BaseStateMachine/MachineState/ExecuteState"
METHODS: tuple[Method, ...] = (
    Method("BaseStateMachine/Abort", "packml", "abort: the robot stops at once", command=PackMLCommand.ABORT),
    Method("BaseStateMachine/Clear", "packml", "Aborted -> Clearing -> Stopped", command=PackMLCommand.CLEAR),
    Method("BaseStateMachine/MachineState/Stop", "packml", "stop in order", command=PackMLCommand.STOP),
    Method("BaseStateMachine/MachineState/Reset", "packml", "Stopped/Complete -> Resetting -> Idle", command=PackMLCommand.RESET),
    Method(f"{_EXEC}/Start", "packml", "Idle -> Starting -> Execute", command=PackMLCommand.START),
    Method(f"{_EXEC}/Hold", "packml", "hold (internal cause)", command=PackMLCommand.HOLD),
    Method(f"{_EXEC}/Unhold", "packml", "Held -> Unholding -> Execute", command=PackMLCommand.UNHOLD),
    Method(f"{_EXEC}/Suspend", "packml", "suspend (external cause)", command=PackMLCommand.SUSPEND),
    Method(f"{_EXEC}/Unsuspend", "packml", "Suspended -> Unsuspending -> Execute", command=PackMLCommand.UNSUSPEND),
    Method(f"{_EXEC}/ToComplete", "packml", "Execute -> Completing -> Complete (refused while a cycle runs)",
           command=PackMLCommand.COMPLETE),
    Method("SetUnitMode", "packml", "change the unit mode (allowed in the states [packml] mode_change_states names)",
           inputs=(Arg("UnitMode", "Int32", "1 production, 2 maintenance, 3 manual"),)),
    Method("Cycle/StartCycle", "cellctl",
           "start one install; idempotent on RequestId (a repeated id answers the same CycleId and starts nothing; the "
           "same id with another Recipe, PartId or CarId answers BadInvalidArgument)",
           inputs=(Arg("Recipe", "String", "recipe name ([[process.recipes]])"),
                   Arg("PartId", "String", "the glass's part id"),
                   Arg("CarId", "String", "the car body's id (may be empty)"),
                   Arg("RequestId", "String", "the caller's idempotency key, unique per intended install")),
           outputs=(Arg("CycleId", "UInt32", "the cycle made for RequestId"),)),
    Method("Cycle/GetResult", "cellctl", "the result of the cycle made for RequestId, once it has finished",
           inputs=(Arg("RequestId", "String", "StartCycle's RequestId"),),
           outputs=(Arg("Finished", "Boolean", "false while the cycle runs"),
                    Arg("Ok", "Boolean", "installed and measured within the tolerance"),
                    Arg("ErrorCode", "UInt16", "0 when Ok, else the alarm id"),
                    Arg("Reason", "String", "why it is not Ok"),
                    Arg("MeasuredDeviation", "Double", "[dx, dy, dz mm, drx, dry, drz deg], empty if not measured", array=True),
                    Arg("CycleTime", "Double", "s")),
           read_only=True),
)  # fmt: skip

UNIT_MODES = (UnitMode.PRODUCTION, UnitMode.MAINTENANCE, UnitMode.MANUAL)
ALARM_SEVERITY = {1: 300, 2: 600, 3: 900}
"""The cell's alarm severity (warning, error, critical) as OPC UA event severity (1..1000)."""


def node_id_text(cell_id: str, path: str) -> str:
    """The string node id of ``path`` below the cell object."""
    return f"{cell_id}.{path.replace('/', '.')}" if path else cell_id


def folders() -> tuple[tuple[str, Namespace], ...]:
    """Every object node the variables and methods need, parents first, with the namespace of its browse name."""
    ns_of = {"Status": "packml", "Admin": "packml", "BaseStateMachine": "packml", "BaseStateMachine/MachineState": "packml",
             _EXEC: "packml"}  # fmt: skip
    seen: dict[str, Namespace] = {}
    for item in (*VARIABLES, *METHODS):
        parts = item.path.split("/")[:-1]
        for k in range(1, len(parts) + 1):
            p = "/".join(parts[:k])
            if p.endswith("CurrentState"):
                continue
            seen.setdefault(p, ns_of.get(p, "cellctl"))  # type: ignore[arg-type]
    return tuple(seen.items())
