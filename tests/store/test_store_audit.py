"""Store: the append-only, hash-chained audit log, fed from the PackML machine."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from cellctl.cell.packml import PackMLMachine
from cellctl.cell.tags import CycleStep, PackMLCommand, UnitMode
from cellctl.store import AuditChainBroken, CellStore
from cellctl.store.audit import GENESIS_HASH


@pytest.fixture
def db(tmp_path: Path) -> Path:
    return tmp_path / "cell.db"


async def test_machine_events_become_audit_entries(db: Path) -> None:
    store = CellStore.open(db)
    m = PackMLMachine()
    m.subscribe(lambda ev: store.append_machine_event(ev))
    await m.command(PackMLCommand.CLEAR, actor="alice", source="10.0.0.7")
    await m.state_complete(actor="system", source="orchestrator")
    await m.change_mode(UnitMode.MAINTENANCE, actor="alice", source="10.0.0.7")
    await m.command(PackMLCommand.RESET, actor="alice", source="10.0.0.7")
    await m.state_complete()
    await m.command(PackMLCommand.START, actor="plc", source="modbus")
    await m.state_complete()
    await m.set_cycle_step(CycleStep.ALIGN)
    entries = store.audit_entries()
    got = [(e.seq, e.actor, e.source, e.action, e.state_before, e.state_after) for e in entries]
    assert got == [
        (1, "alice", "10.0.0.7", "command:clear", "ABORTED", "CLEARING"),
        (2, "system", "orchestrator", "state_complete", "CLEARING", "STOPPED"),
        (3, "alice", "10.0.0.7", "mode", "STOPPED", "STOPPED"),
        (4, "alice", "10.0.0.7", "command:reset", "STOPPED", "RESETTING"),
        (5, "system", "cell", "state_complete", "RESETTING", "IDLE"),
        (6, "plc", "modbus", "command:start", "IDLE", "STARTING"),
        (7, "system", "cell", "state_complete", "STARTING", "EXECUTE"),
        (8, "system", "cell", "cycle_step", "EXECUTE", "EXECUTE"),
    ]
    assert entries[2].params == {"event_seq": 3, "mode_before": "PRODUCTION", "mode_after": "MAINTENANCE"}
    assert entries[7].params == {"event_seq": 8, "step_before": "NONE", "step_after": "ALIGN"}
    assert entries[0].prev_hash == GENESIS_HASH and entries[1].prev_hash == entries[0].hash
    assert store.verify_audit_chain() == 8
    assert [e.seq for e in store.audit_entries(after_seq=6)] == [7, 8]
    store.close()


def test_audit_log_refuses_update_and_delete(db: Path) -> None:
    store = CellStore.open(db)
    store.append_audit(actor="bob", source="hmi", action="alarm:ack", params={"uid": "x"}, result="ok")
    store.close()
    raw = sqlite3.connect(db)
    with pytest.raises(sqlite3.IntegrityError, match="append-only: entries cannot be changed"):
        raw.execute("UPDATE audit_log SET actor = 'mallory'")
    with pytest.raises(sqlite3.IntegrityError, match="append-only: entries cannot be deleted"):
        raw.execute("DELETE FROM audit_log")
    assert raw.execute("SELECT actor FROM audit_log").fetchall() == [("bob",)]
    raw.close()


def test_hash_chain_detects_tampering_behind_the_triggers(db: Path) -> None:
    store = CellStore.open(db)
    for i in range(4):
        store.append_audit(actor="op", source="hmi", action=f"a{i}", params={"i": i})
    assert store.verify_audit_chain() == 4
    raw = sqlite3.connect(db, isolation_level=None)
    raw.execute("DROP TRIGGER audit_log_append_only_update")  # someone with file access
    raw.execute("UPDATE audit_log SET params_json = '{\"i\":99}' WHERE seq = 2")
    with pytest.raises(AuditChainBroken, match="entry 2: its content does not match its hash"):
        store.verify_audit_chain()
    raw.execute("DROP TRIGGER audit_log_append_only_delete")
    raw.execute("UPDATE audit_log SET params_json = '{\"i\":1}' WHERE seq = 2")
    raw.execute("DELETE FROM audit_log WHERE seq = 3")
    with pytest.raises(AuditChainBroken, match="entry 4: expected entry 3 here"):
        store.verify_audit_chain()
    raw.close()
    store.close()


def test_audit_input_is_checked(db: Path) -> None:
    with CellStore.open(db) as store:
        with pytest.raises(ValueError, match="actor must be a non-empty string"):
            store.append_audit(actor="", source="hmi", action="x")
        with pytest.raises(ValueError, match="NaN"):
            store.append_audit(actor="a", source="hmi", action="x", params={"v": float("inf")})
        assert store.verify_audit_chain() == 0
