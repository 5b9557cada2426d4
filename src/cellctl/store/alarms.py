"""Alarms in the store: one row per alarm occurrence, updated on every alarm event.

The row is the :class:`cellctl.domain.Alarm` record (PackML ``PackMLAlarmDataType`` plus severity,
source, reaction and cycle), keyed by its ``uid``. Startup recovery closes rows left active
(:meth:`cellctl.store.db.CellStore.recover`); retention deletes old inactive ones
(:meth:`cellctl.store.retention.RetentionRows.prune_alarms`).
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from cellctl.domain import Alarm, AlarmCode, FaultClass, PackMLCommand, Severity
from cellctl.store.connection import Database, dt, ts


class AlarmRows(Database):
    """The alarm methods of :class:`cellctl.store.db.CellStore`."""

    def save_alarm(self, alarm: Alarm) -> None:
        """Insert or update an alarm record (call it on every alarm event)."""
        with self._tx() as c:
            c.execute(
                "INSERT INTO alarms (uid, code, value, message, category, severity, source, raised_at, active, "
                "condition, ack_at, ack_by, cleared_at, reaction, cycle_id) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) "
                "ON CONFLICT (uid) DO UPDATE SET active = excluded.active, ack_at = excluded.ack_at, "
                "ack_by = excluded.ack_by, cleared_at = excluded.cleared_at, reaction = excluded.reaction",
                (
                    alarm.uid, int(alarm.code), alarm.value, alarm.message, int(alarm.category),
                    int(alarm.severity), alarm.source, ts(alarm.raised_at), int(alarm.active),
                    int(alarm.condition), None if alarm.ack_at is None else ts(alarm.ack_at), alarm.ack_by,
                    None if alarm.cleared_at is None else ts(alarm.cleared_at),
                    None if alarm.reaction is None else int(alarm.reaction), alarm.cycle_id,
                ),
            )  # fmt: skip

    def unacknowledged_alarms(self, limit: int = 100) -> list[Alarm]:
        """Alarms nobody acknowledged, the newest ``limit``, oldest first: a restart lists them again."""
        sql = f"SELECT {ALARM_COLUMNS} FROM alarms WHERE ack_at IS NULL ORDER BY raised_at DESC LIMIT ?"
        return [alarm_from_row(r) for r in reversed(self._conn.execute(sql, (limit,)).fetchall())]

    def alarms(self, *, active_only: bool = False, limit: int = 100) -> list[Alarm]:
        """Newest first."""
        sql = f"SELECT {ALARM_COLUMNS} FROM alarms"
        if active_only:
            sql += " WHERE active = 1"
        sql += " ORDER BY raised_at DESC LIMIT ?"
        return [alarm_from_row(r) for r in self._conn.execute(sql, (limit,))]


ALARM_COLUMNS = (
    "uid, code, value, message, category, severity, source, raised_at, active, condition, ack_at, ack_by, "
    "cleared_at, reaction, cycle_id"
)
"""The columns of ``alarms`` that :func:`alarm_from_row` reads, in its order."""


def alarm_from_row(r: tuple[Any, ...]) -> Alarm:
    """An ``alarms`` row (:data:`ALARM_COLUMNS`) as its record."""
    return Alarm(
        uid=r[0],
        code=AlarmCode(r[1]),
        value=int(r[2]),
        message=r[3],
        category=FaultClass(r[4]),
        severity=Severity(r[5]),
        source=r[6],
        raised_at=datetime.fromisoformat(r[7]),
        active=bool(r[8]),
        condition=bool(r[9]),
        ack_at=dt(r[10]),
        ack_by=r[11],
        cleared_at=dt(r[12]),
        reaction=None if r[13] is None else PackMLCommand(r[13]),
        cycle_id=r[14],
    )
