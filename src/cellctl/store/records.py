"""What the store keeps and hands back (plain frozen records), and its errors."""

from __future__ import annotations

import enum
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from datetime import datetime
from typing import Any

from cellctl.domain import CycleStep

MAX_TEXT_LEN = 128

# The one definition of the text a request's names and ids may hold; the REST API's request bodies carry the same
# patterns (so its OpenAPI document says it) and check them with text_problem (so its 422 says it in words).
_CONTROL = r"\x00-\x1f"  # control characters, U+0000 to U+001F (tab, newline, carriage return, ...)
# How a requester retries a cycle that never installed: each interface's request id answers its first cycle again.
REQUEST_AGAIN = ("request it again with a new request id (REST Idempotency-Key, PLC cycle_req_id, OPC UA RequestId): "
                 "the same id answers this cycle again")
INTERRUPTED_REASONS = (  # queued, running before the install, running after the install began
    f"interrupted: the service stopped before the cycle began; {REQUEST_AGAIN}",
    f"interrupted: the service stopped before the install; nothing was installed, {REQUEST_AGAIN}",
    "interrupted: the service stopped after the install began; check the glass by hand, the install is never repeated",
)
"""An interrupted cycle's reason (REST, the PLC, OPC UA and MQTT show it), by how far it had got."""
TEXT_PATTERN = rf"^[^{_CONTROL}]*$"
"""Optional text (a car body's id): no control characters."""
NAME_PATTERN = rf"^[^{_CONTROL}]*[^{_CONTROL}\s][^{_CONTROL}]*$"
"""Required text (recipe, part id, source): no control characters, and at least one character that is not white space."""
TEXT_ALLOWED = "printable text: no control characters (U+0000 to U+001F: tab, newline, ...)"
NAME_ALLOWED = f"{TEXT_ALLOWED}, and not empty or only white space"


class CycleState(str, enum.Enum):
    QUEUED = "queued"
    RUNNING = "running"
    DONE = "done"  # ran to its end and installed; ``result`` says how well
    FAILED = "failed"  # ended without installing (NOK, fault, abort); ``error`` says why
    INTERRUPTED = "interrupted"  # the process died while it was queued or running


def text_problem(value: str, *, required: bool) -> str | None:
    """What is wrong with ``value`` as a required (:data:`NAME_PATTERN`) or optional (:data:`TEXT_PATTERN`)
    text, and what to give instead; None when it matches."""
    if re.fullmatch(NAME_PATTERN if required else TEXT_PATTERN, value):
        return None
    allowed = NAME_ALLOWED if required else TEXT_ALLOWED
    if re.search(f"[{_CONTROL}]", value):
        return f"contains control characters; use {allowed}"
    return f"must not be empty or only white space; use {allowed}"


def _check_text(name: str, value: object, *, required: bool) -> None:
    if value is None and not required:
        return
    if not isinstance(value, str):
        raise ValueError(f"{name} must be a string, got {type(value).__name__}")
    problem = text_problem(value, required=required)
    if problem is not None:
        raise ValueError(f"{name} {problem}")
    if len(value) > MAX_TEXT_LEN:
        raise ValueError(f"{name} is {len(value)} characters long; at most {MAX_TEXT_LEN} are allowed")


@dataclass(frozen=True)
class CycleRequest:
    """What was asked for. The idempotency check compares :meth:`identity` (source is metadata:
    a retry from another client address is still the same request)."""

    recipe: str
    part_id: str
    car_id: str | None = None
    source: str = "api"
    plc_recipe_id: int | None = None
    """The line PLC's recipe_id of a PLC-started cycle, kept in its idempotency key's request (so a later change of
    ``[[process.recipes]]`` ids or names does not change it); None for other cycles, older records, or once the key is
    forgotten."""

    def __post_init__(self) -> None:
        _check_text("recipe", self.recipe, required=True)
        _check_text("part_id", self.part_id, required=True)
        _check_text("car_id", self.car_id, required=False)
        _check_text("source", self.source, required=True)
        n = self.plc_recipe_id
        if n is not None and (isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= 0xFFFF):
            raise ValueError(f"plc_recipe_id must be a PLC recipe_id (0..65535) or None, got {n!r}")

    def identity(self) -> dict[str, str | int | None]:
        """What the idempotency check compares; ``plc_recipe_id`` only when there is one (other keys hash as before)."""
        ident: dict[str, str | int | None] = {"recipe": self.recipe, "part_id": self.part_id, "car_id": self.car_id}
        if self.plc_recipe_id is not None:
            ident["plc_recipe_id"] = self.plc_recipe_id
        return ident

    def with_stored(self, request_json: str | None) -> CycleRequest:
        """This request with the ``plc_recipe_id`` its idempotency key's stored request holds (if any)."""
        n = None if request_json is None else json.loads(request_json).get("plc_recipe_id")
        return self if not isinstance(n, int) or isinstance(n, bool) else replace(self, plc_recipe_id=n)


@dataclass(frozen=True)
class StepRecord:
    """One run of one cycle step (compensate's verification shots make several SHOOT attempts)."""

    step: CycleStep
    attempt: int
    started_at: datetime
    finished_at: datetime | None
    duration_s: float | None
    ok: bool | None
    figures: Mapping[str, Any]
    error: str | None


@dataclass(frozen=True)
class ImageRef:
    """An image of a cycle: the file ``uri`` (relative to the image folder) and, once retention
    deleted the file, when and why (the reference itself is kept as long as its cycle record).

    ``sha256`` (lower-case hex) and ``size_bytes`` are those of the file as written, for
    traceability; both None for images recorded before the store kept them (schema version 5).
    """

    step: CycleStep
    name: str
    uri: str
    created_at: datetime
    pruned_at: datetime | None = None
    pruned_reason: str | None = None
    sha256: str | None = None
    size_bytes: int | None = None

    @property
    def pruned(self) -> bool:
        return self.pruned_at is not None


@dataclass(frozen=True)
class CycleRecord:
    """A cycle with its inputs, steps, result and timings.

    ``true_error`` is the simulated cell's known error of the install (None on hardware).
    ``install_started_at`` is the marker written before the robot is commanded to install.
    """

    id: int
    idempotency_scope: str
    idempotency_key: str
    request: CycleRequest
    actor: str
    state: CycleState
    current_step: CycleStep
    result: Mapping[str, Any] | None
    error: str | None
    true_error: Mapping[str, Any] | None
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    install_started_at: datetime | None
    interrupted_step: CycleStep | None
    interrupted_at: datetime | None
    steps: tuple[StepRecord, ...] = ()
    images: tuple[ImageRef, ...] = ()

    @property
    def install_started(self) -> bool:
        return self.install_started_at is not None

    @property
    def duration_s(self) -> float | None:
        if self.started_at is None or self.finished_at is None:
            return None
        return (self.finished_at - self.started_at).total_seconds()


@dataclass(frozen=True)
class SubmitResult:
    cycle: CycleRecord
    created: bool  # False: the idempotency key was seen before with the same request


@dataclass(frozen=True)
class StoredResponse:
    """A finished idempotent request's answer, to replay."""

    scope: str
    key: str
    response: Mapping[str, Any]
    completed_at: datetime


@dataclass(frozen=True)
class InterruptedCycle:
    cycle_id: int
    was: CycleState
    step: CycleStep
    install_started: bool

    @property
    def resumable(self) -> bool:
        return not self.install_started


@dataclass(frozen=True)
class RecoveryReport:
    """What startup recovery found after an unclean stop."""

    interrupted: tuple[InterruptedCycle, ...]
    alarms_closed: int
    keys_released: int


@dataclass(frozen=True)
class AuditEntry:
    seq: int
    at: datetime
    actor: str
    source: str
    action: str
    params: Mapping[str, Any]
    state_before: str | None
    state_after: str | None
    result: str
    cycle_id: int | None
    prev_hash: str
    hash: str


# --- Errors --------------------------------------------------------------------------------------


class StoreError(Exception):
    """The store cannot do what was asked."""


class SchemaTooNew(StoreError):
    """The database was written by a newer cellctl."""


class UnknownCycle(StoreError, KeyError):
    def __init__(self, cycle_id: int) -> None:
        super().__init__(f"no cycle with id {cycle_id}")
        self.cycle_id = cycle_id

    def __str__(self) -> str:
        return f"no cycle with id {self.cycle_id}"


class CycleStateError(StoreError):
    """The cycle is not in a state that allows this (e.g. finishing a cycle that never started)."""

    def __init__(self, cycle_id: int, message: str) -> None:
        super().__init__(f"cycle {cycle_id}: {message}")
        self.cycle_id = cycle_id


class InstallAlreadyStarted(CycleStateError):
    """The install step of this cycle was started once; it is never run again."""

    def __init__(self, cycle_id: int, started_at: datetime) -> None:
        super().__init__(
            cycle_id,
            f"the install step was started at {started_at.isoformat()} and is never repeated; "
            "inspect the part and request a new cycle",
        )
        self.started_at = started_at


class IdempotencyConflict(StoreError):
    """The key was used before with a different request (the API answers 422)."""

    def __init__(self, scope: str, key: str, differences: Mapping[str, tuple[object, object]]) -> None:
        diff = ", ".join(f"{f} {old!r} then {new!r}" for f, (old, new) in differences.items())
        super().__init__(
            f"idempotency key {key!r} ({scope}) was already used for a different request ({diff}); "
            "use a new key for a new request"
        )
        self.scope = scope
        self.key = key
        self.differences = dict(differences)


class IdempotencyInFlight(StoreError):
    """The first request with this key has not finished yet (the API answers 409)."""

    def __init__(self, scope: str, key: str) -> None:
        super().__init__(f"a request with idempotency key {key!r} ({scope}) is still in progress; retry later")
        self.scope = scope
        self.key = key


class AuditChainBroken(StoreError):
    """The audit log's hash chain does not verify: an entry was altered or removed."""

    def __init__(self, seq: int, why: str) -> None:
        super().__init__(f"audit log entry {seq}: {why}")
        self.seq = seq

__all__ = [
    "AuditChainBroken", "AuditEntry", "CycleRecord", "CycleRequest", "CycleState", "CycleStateError",
    "IdempotencyConflict", "IdempotencyInFlight", "ImageRef", "InstallAlreadyStarted", "InterruptedCycle",
    "RecoveryReport", "REQUEST_AGAIN", "SchemaTooNew", "StepRecord", "StoredResponse", "StoreError", "SubmitResult",
    "UnknownCycle",
]
