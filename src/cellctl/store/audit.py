"""The audit log in the store: append-only and hash-chained, who commanded what and when.

Each entry carries the hash of the previous one (the first links to :data:`GENESIS_HASH`), so an
entry altered or removed behind the schema's append-only triggers breaks the chain, which
:meth:`AuditRows.verify_audit_chain` finds. Retention never prunes this table.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from datetime import datetime
from typing import Any

from cellctl.domain import EventKind, MachineEvent
from cellctl.store.connection import Database, need, to_json, ts
from cellctl.store.records import AuditChainBroken, AuditEntry

GENESIS_HASH = "0" * 64
"""The ``prev_hash`` of the first entry."""


class AuditRows(Database):
    """The audit-log methods of :class:`cellctl.store.db.CellStore`."""

    def append_audit(
        self,
        *,
        actor: str,
        source: str,
        action: str,
        params: Mapping[str, Any] | None = None,
        state_before: str | None = None,
        state_after: str | None = None,
        result: str = "ok",
        cycle_id: int | None = None,
        at: datetime | None = None,
    ) -> AuditEntry:
        """Append one entry; each carries the hash of the previous one (tamper evidence)."""
        need("actor", actor)
        need("source", source)
        need("action", action)
        params_json = to_json("audit params", dict(params or {}))
        when = ts(at or self._clock())
        with self._tx() as c:
            last = c.execute("SELECT seq, hash FROM audit_log ORDER BY seq DESC LIMIT 1").fetchone()
            seq, prev = (1, GENESIS_HASH) if last is None else (int(last[0]) + 1, str(last[1]))
            fields = (seq, when, actor, source, action, params_json, state_before, state_after, result, cycle_id)
            digest = _audit_hash(prev, fields)
            c.execute(
                "INSERT INTO audit_log (seq, at, actor, source, action, params_json, state_before, state_after, "
                "result, cycle_id, prev_hash, hash) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (*fields, prev, digest),
            )
        return AuditEntry(seq, datetime.fromisoformat(when), actor, source, action, json.loads(params_json),
                          state_before, state_after, result, cycle_id, prev, digest)  # fmt: skip

    def append_machine_event(self, event: MachineEvent, *, cycle_id: int | None = None) -> AuditEntry:
        """The audit entry of a PackML machine event (command, SC, mode change or cycle step)."""
        if event.kind == EventKind.COMMAND:
            assert event.command is not None
            action = f"command:{event.command.name.lower()}"
        else:
            action = event.kind.value
        params: dict[str, Any] = {"event_seq": event.seq}
        if event.kind == EventKind.MODE:
            params.update(mode_before=event.mode_before.name, mode_after=event.mode_after.name)
        if event.step_before != event.step_after:
            params.update(step_before=event.step_before.name, step_after=event.step_after.name)
        return self.append_audit(
            actor=event.actor,
            source=event.source,
            action=action,
            params=params,
            state_before=event.state_before.name,
            state_after=event.state_after.name,
            cycle_id=cycle_id,
            at=event.at,
        )

    def audit_entries(self, *, after_seq: int = 0, limit: int = 100) -> list[AuditEntry]:
        """Oldest first, from ``after_seq`` on."""
        return [
            audit_entry(r)
            for r in self._conn.execute(
                f"SELECT {AUDIT_COLUMNS} FROM audit_log WHERE seq > ? ORDER BY seq LIMIT ?", (after_seq, limit)
            )
        ]

    def verify_audit_chain(self) -> int:
        """Recompute the hash chain; returns the number of entries, raises AuditChainBroken."""
        prev = GENESIS_HASH
        expected_seq = 1
        for r in self._conn.execute(f"SELECT {AUDIT_COLUMNS} FROM audit_log ORDER BY seq"):
            seq = int(r[0])
            if seq != expected_seq:
                raise AuditChainBroken(seq, f"expected entry {expected_seq} here: entries are missing")
            if r[10] != prev:
                raise AuditChainBroken(seq, "does not link to the previous entry")
            if _audit_hash(prev, tuple(r[:10])) != r[11]:
                raise AuditChainBroken(seq, "its content does not match its hash")
            prev = r[11]
            expected_seq += 1
        return expected_seq - 1


AUDIT_COLUMNS = (
    "seq, at, actor, source, action, params_json, state_before, state_after, result, cycle_id, prev_hash, hash"
)
"""The columns of ``audit_log`` that :func:`audit_entry` reads, in its order."""


def audit_entry(r: Sequence[Any]) -> AuditEntry:
    """An ``audit_log`` row (:data:`AUDIT_COLUMNS`) as its entry."""
    return AuditEntry(r[0], datetime.fromisoformat(r[1]), r[2], r[3], r[4], json.loads(r[5]), r[6], r[7], r[8],
                      r[9], r[10], r[11])  # fmt: skip


def _audit_hash(prev: str, fields: tuple[Any, ...]) -> str:
    payload = json.dumps([prev, *fields], separators=(",", ":"), ensure_ascii=False)
    return hashlib.sha256(payload.encode()).hexdigest()
