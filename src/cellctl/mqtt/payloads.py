"""The JSON payloads the cell publishes (docs/mqtt.md shows one of each).

Every payload is a JSON object with the envelope: ``v`` (the schema's major version; additive
changes keep it), ``ts`` (when it was made, UTC, RFC 3339), ``msg_id`` (unique, uuid4 hex: a
subscriber drops a message whose id it has seen) and ``seq`` (the cell's message sequence,
increasing, durable across restarts; the outbox writes it, :func:`encode` for messages sent
directly). Units are in the field names (``cycle_time_s``, ``dx_mm``, ``drz_deg``).
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

from cellctl.domain import Alarm, CycleStep, PackMLState, UnitMode

SCHEMA_VERSION = 1


def rfc3339(t: datetime) -> str:
    """A timezone-aware time as UTC RFC 3339 with milliseconds and ``Z``."""
    if t.tzinfo is None:
        raise ValueError("payload times must be timezone-aware")
    return t.astimezone(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def envelope(*, now: datetime | None = None, msg_id: str | None = None) -> dict[str, Any]:
    """``v``, ``ts`` and ``msg_id`` (``seq`` is added where the message gets its place in the sequence)."""
    return {
        "v": SCHEMA_VERSION,
        "ts": rfc3339(now or datetime.now(UTC)),
        "msg_id": msg_id or uuid.uuid4().hex,
    }


def encode(body: Mapping[str, Any] | None, *, seq: int | None = None) -> bytes:
    """The payload's bytes: canonical JSON (sorted keys) with ``seq`` if given; None is the empty message."""
    if body is None:
        return b""
    full = dict(body) if seq is None else {**body, "seq": int(seq)}
    return json.dumps(full, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


def result(message: Mapping[str, Any], **env: Any) -> dict[str, Any]:
    """A finished cycle's result (:func:`cellctl.cell.outcome.result_message`) in the envelope."""
    return {**envelope(**env), **message}


def state(state_name: str, mode_name: str, step_name: str, **env: Any) -> dict[str, Any]:
    """The PackML state and unit mode (PackTags integer and name) and the cycle step (Execute's sub-state)."""
    st, mode, step = PackMLState[state_name.upper()], UnitMode[mode_name.upper()], CycleStep[step_name.upper()]
    return {
        **envelope(**env),
        "state": st.name, "state_id": int(st), "mode": mode.name, "mode_id": int(mode),
        "cycle_step": step.name.lower(), "cycle_step_id": int(step),
    }  # fmt: skip


def _time(t: datetime | None) -> str | None:
    return None if t is None else rfc3339(t)


def alarm(a: Alarm, *, event: str | None = None, **env: Any) -> dict[str, Any]:
    """An alarm occurrence as it stands (and, on ``alarm/events``, what just happened to it)."""
    body: dict[str, Any] = {
        **envelope(**env),
        "uid": a.uid, "code": int(a.code), "name": a.code.name.lower(), "value": a.value, "message": a.message,
        "category": a.category.name.lower(), "severity": a.severity.name.lower(), "source": a.source,
        "active": a.active, "acknowledged": a.acknowledged, "raised_at": _time(a.raised_at),
        "cleared_at": _time(a.cleared_at), "acknowledged_at": _time(a.ack_at), "acknowledged_by": a.ack_by,
        "cycle_id": a.cycle_id,
    }  # fmt: skip
    if event is not None:
        body["event"] = event
    return body


def calibration(reference: Mapping[str, Any], **env: Any) -> dict[str, Any]:
    """The calibration set in use: its version (None before the first, or the twin's truth) and its parts' ids."""
    version = reference.get("version")
    return {
        **envelope(**env),
        "version": None if version is None else str(version),
        "parts": dict(reference.get("parts") or {}),
        "damaged": bool(reference.get("damaged", False)),
    }


def status(
    *, online: bool, client_id: str, reason: str, pending: int | None = None, dropped_total: int | None = None,
    dropped_results_total: int | None = None, **env: Any,
) -> dict[str, Any]:  # fmt: skip
    """The connection's status: ``online`` true at connect; false in the will and at a clean stop."""
    body: dict[str, Any] = {**envelope(**env), "online": online, "client_id": client_id, "reason": reason}
    if pending is not None:
        body.update(outbox_pending=pending, dropped_total=dropped_total, dropped_results_total=dropped_results_total)
    return body


def dropped(*, dropped: int, dropped_results: int, dropped_total: int, max_messages: int, **env: Any) -> dict[str, Any]:
    """How many messages the outbox's bound dropped unsent since the last report (and in all)."""
    return {
        **envelope(**env),
        "dropped": dropped, "dropped_results": dropped_results, "dropped_total": dropped_total,
        "max_messages": max_messages,
    }  # fmt: skip
