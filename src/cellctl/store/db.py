"""The cell's SQLite store (WAL mode): cycles, alarms, audit log, idempotency keys, commissioning jobs,
the closed-loop offset.

:class:`CellStore` is the one object the rest of the code opens. It is made of one repository per
aggregate, each in its own module, all sharing one connection
(:class:`~cellctl.store.connection.Database`, which they subclass):

==============================================  ===========================================================
:class:`~cellctl.store.cycles.CycleRows`        cycles, their steps and image references, idempotency keys
:class:`~cellctl.store.alarms.AlarmRows`        alarm records
:class:`~cellctl.store.audit.AuditRows`         the hash-chained audit log
:class:`~cellctl.store.jobs.JobRows`            commissioning jobs
:class:`~cellctl.store.spc.SpcRows`             the closed-loop offset: its state and history
:class:`~cellctl.store.parts.PartRows`          part traceability: installs by car body, glass, time
:class:`~cellctl.store.retention.RetentionRows` pruning and the database's size
:class:`~cellctl.store.outbox.OutboxRows`       the MQTT outbox: messages the broker has not acknowledged
==============================================  ===========================================================

What spans them lives here: :meth:`CellStore.recover` after an unclean stop.

This class is synchronous and owns one connection; it must be used from the thread that opened
it (sqlite3's default check). The service uses it through :class:`cellctl.store.aio.AsyncCellStore`,
which runs every call on one dedicated thread.

Durability: every method that changes something commits before it returns (``synchronous=FULL``
by default, so a commit also survives a power cut). In particular :meth:`begin_step` for the
install step writes the install-started marker and commits *before* the caller commands the
robot; a cycle with that marker never gets its install step again, whatever happens.
"""

from __future__ import annotations

import sqlite3

from cellctl.domain import CycleStep
from cellctl.store.alarms import AlarmRows
from cellctl.store.audit import AuditRows
from cellctl.store.connection import StoreInfo, ts
from cellctl.store.cycles import CycleRows, end_stamp
from cellctl.store.jobs import JobRows
from cellctl.store.outbox import OutboxRows
from cellctl.store.parts import PartRows
from cellctl.store.records import INTERRUPTED_REASONS, CycleState, InterruptedCycle, RecoveryReport, StoreError
from cellctl.store.retention import RetentionRows
from cellctl.store.schema import cut_off_at
from cellctl.store.spc import SpcRows


RECOVER_TRIES = 3
"""How often startup's recovery asks for the write lock another process holds (each waits ``busy_timeout_s``)."""


class StoreLocked(StoreError):
    """Another process holds the database's write lock (a backup, an sqlite3 shell) past the start's retries; the
    message names ``[store] path`` and what to do. A restart may find it free (``serve`` exits 1)."""


def is_locked(err: sqlite3.OperationalError) -> bool:
    """SQLite's "database is locked" or "busy": another connection holds the lock."""
    return getattr(err, "sqlite_errorcode", None) in (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED) or "locked" in str(err)


class CellStore(CycleRows, AlarmRows, AuditRows, JobRows, SpcRows, RetentionRows, PartRows, OutboxRows):
    """Open with :meth:`open`; close with :meth:`close` (or use as a context manager)."""

    def recover(self) -> RecoveryReport:
        """:meth:`recover_once`, asked again while another process holds the write lock (:data:`RECOVER_TRIES` times,
        each waiting ``busy_timeout_s``), then :class:`StoreLocked` naming the file."""
        for _ in range(RECOVER_TRIES - 1):
            try:
                return self.recover_once()
            except sqlite3.OperationalError as err:
                if not is_locked(err):
                    raise
        try:
            return self.recover_once()
        except sqlite3.OperationalError as err:
            if not is_locked(err):
                raise
            waited = RECOVER_TRIES * self._conn.execute("PRAGMA busy_timeout").fetchone()[0] / 1000
            raise StoreLocked(
                f"[store] path {self._path}: another process holds the database's lock (waited {waited:g} s): a backup or "
                f"an sqlite3 shell? `fuser {self._path}` names it; end it, then start the service again"
            ) from None

    def recover_once(self) -> RecoveryReport:
        """Run once at startup, before anything else writes.

        Every cycle left queued or running by a process that died becomes ``interrupted`` with
        the step it was in, ``interrupted_at`` when it was cut off as far as its record shows (its
        newest step start or end or image, else its start, else its submission; UTC),
        ``interrupted_found_at`` now and its end stamp (:func:`~cellctl.store.cycles.end_stamp`); steps
        left open get an error; alarms left active are closed (the watchdog re-raises what is still
        wrong); in-flight idempotency keys of non-cycle requests are released (their effect is unknown;
        the cell restarts in Aborted anyway).
        Calling it again finds nothing.
        """
        clock = self._clock()
        now = ts(clock)
        with self._tx() as c:
            rows = c.execute(
                "SELECT id, state, current_step, install_started_at FROM cycles "
                "WHERE state IN ('queued', 'running') ORDER BY id"
            ).fetchall()
            found = tuple(
                InterruptedCycle(int(r[0]), CycleState(r[1]), CycleStep(r[2]), r[3] is not None) for r in rows
            )
            ended = end_stamp(c, clock) if found else None  # the latest end stamp moves only when a cycle ends
            c.execute(  # with its reason, as a failed cycle has one (REST, the PLC, OPC UA and MQTT show it)
                "UPDATE cycles SET state = 'interrupted', interrupted_step = current_step, "
                f"interrupted_at = {cut_off_at(':found')}, interrupted_found_at = :found, ended_at = :ended, "
                "error = COALESCE(error, CASE WHEN state = 'queued' THEN :queued WHEN install_started_at IS NULL "
                "THEN :before ELSE :after END) WHERE state IN ('queued', 'running')",
                dict(zip(("found", "ended", "queued", "before", "after"), (now, ended, *INTERRUPTED_REASONS), strict=True)),
            )
            c.execute(
                "UPDATE cycle_steps SET error = 'interrupted: the cell process stopped during this step' "
                "WHERE finished_at IS NULL AND error IS NULL AND cycle_id IN "
                f"({','.join(str(i.cycle_id) for i in found) or 'NULL'})"
            )
            alarms = c.execute("UPDATE alarms SET active = 0, cleared_at = ? WHERE active = 1", (now,)).rowcount
            keys = c.execute(
                "DELETE FROM idempotency_keys WHERE response_json IS NULL AND cycle_id IS NULL"
            ).rowcount
        return RecoveryReport(found, alarms, keys)


__all__ = ["CellStore", "StoreInfo", "StoreLocked"]
