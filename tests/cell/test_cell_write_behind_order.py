"""The store's write-behind queue keeps the order of events (the audit log's hash chain): two writes issued back to
back while another process holds the database's lock (the first times out and is kept; the lock is released before
the second tries) are written first to last, and alarm 1703 stays while anything is kept. The peer: a second sqlite3
connection holding the lock and reading audit_log back."""
from __future__ import annotations

import asyncio
import sqlite3
from pathlib import Path


from cellctl.cell.store_faults import WriteBehind
from cellctl.store import AsyncCellStore


async def test_a_write_never_overtakes_one_kept_before_it(tmp_path: Path) -> None:
    db = tmp_path / "cellctl.db"
    store = await AsyncCellStore.open(db, busy_timeout_s=0.2)
    wb = WriteBehind(store, None, retry_s=0.5)
    holder = sqlite3.connect(db, isolation_level=None, timeout=0.1)
    holder.execute("BEGIN IMMEDIATE")  # a backup / sqlite3 shell holding the write lock
    loop = asyncio.get_running_loop()
    loop.call_later(0.3, holder.execute, "COMMIT")  # ... for 0.3 s
    try:
        a = asyncio.ensure_future(wb.audit(actor="op", source="rest", action="A.hold"))
        await asyncio.sleep(0)  # A goes first
        b = asyncio.ensure_future(wb.audit(actor="op", source="rest", action="B.unhold"))
        await a, await b
        await asyncio.sleep(1.5)  # the retry writes what was kept
        await wb.stop()
    finally:
        holder.close()
        await store.close()
    rows = sqlite3.connect(db).execute("SELECT seq, at, action FROM audit_log ORDER BY seq").fetchall()
    assert [r[2] for r in rows] == ["A.hold", "B.unhold"], f"audit log order differs from the events' order: {rows}"


async def test_1703_stays_while_a_write_is_kept(tmp_path: Path) -> None:
    """The alarm clears once all is written, not when a later write gets through while an earlier one is kept."""
    from cellctl.cell.alarms import AlarmManager
    from cellctl.domain import AlarmCode

    db = tmp_path / "cellctl.db"
    store = await AsyncCellStore.open(db, busy_timeout_s=0.2)
    alarms = AlarmManager()
    wb = WriteBehind(store, alarms, retry_s=30.0)  # no retry within the test
    holder = sqlite3.connect(db, isolation_level=None, timeout=0.1)
    holder.execute("BEGIN IMMEDIATE")
    asyncio.get_running_loop().call_later(0.3, holder.execute, "COMMIT")
    try:
        a = asyncio.ensure_future(wb.audit(actor="op", source="rest", action="A.hold"))
        await asyncio.sleep(0)
        b = asyncio.ensure_future(wb.audit(actor="op", source="rest", action="B.unhold"))
        await a, await b
        kept = [k.what for k in wb.kept]
        active = alarms.find_active(AlarmCode.RECORD_WRITE_FAILED, "store")
        rows = sqlite3.connect(db).execute("SELECT action FROM audit_log").fetchall()
    finally:
        holder.close()
        wb._kept.clear()
        if wb._retry is not None:
            wb._retry.cancel()
        await store.close()
    assert not (kept and active is None), f"{kept} not written (sqlite3 sees only {rows}), yet alarm 1703 is cleared"
