"""When a calibration check is due: every N installed glasses or every H hours since the last one.

A check needs the board on the wall, so the cell cannot run it between two cycles by itself;
when one is due it raises the reminder alarm :attr:`AlarmCode.CALIBRATION_CHECK_DUE` (a warning:
production goes on) until ``cellctl calibrate verify`` passes. The count starts at the last
passed check, or at the hand-eye calibration when there has been none, and survives a restart
(it is taken from the job and cycle records).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from datetime import datetime, timezone

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.events import EventHub
from cellctl.config.calibration_procedure import VerifyCalibrationConfig
from cellctl.domain import AlarmCode
from cellctl.store import AsyncCellStore, CycleState

log = logging.getLogger(__name__)
SOURCE = "verify schedule"
HOURS_POLL_S = 60.0


def check_due(cycles_since: int, hours_since: float, config: VerifyCalibrationConfig) -> str | None:
    """Why a check is due (naming the setting), or None."""
    if config.every_cycles and cycles_since >= config.every_cycles:
        return f"{cycles_since} glasses installed since the last check (calibration.procedure.verify.every_cycles = {config.every_cycles})"
    if config.every_hours and hours_since >= config.every_hours:
        return f"{hours_since:.1f} h since the last check (calibration.procedure.verify.every_hours = {config.every_hours:g})"
    return None


class VerifySchedule:
    """Counts installed glasses and hours since the last passed check; raises the reminder when one is due."""

    def __init__(self, config: VerifyCalibrationConfig, store: AsyncCellStore, alarms: AlarmManager, events: EventHub,
                 since: datetime | None) -> None:  # fmt: skip
        self.config = config
        self.store = store
        self.alarms = alarms
        self.events = events
        self.since = since or datetime.now(timezone.utc)
        self.cycles_since = 0
        self._task: asyncio.Task[None] | None = None

    @property
    def enabled(self) -> bool:
        return bool(self.config.every_cycles or self.config.every_hours)

    async def start(self) -> None:
        if not self.enabled:
            return
        self.cycles_since = await self.store.count_finished(CycleState.DONE, since=self.since)  # all of them, in SQL
        queue = self.events.subscribe()
        self._task = asyncio.create_task(self._follow(queue))
        await self.review()

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    def checked(self) -> None:
        """A check passed: start counting again and take the reminder down."""
        self.since = datetime.now(timezone.utc)
        self.cycles_since = 0
        self.alarms.clear(AlarmCode.CALIBRATION_CHECK_DUE, source=SOURCE)

    async def review(self) -> None:
        hours = (datetime.now(timezone.utc) - self.since).total_seconds() / 3600.0
        why = check_due(self.cycles_since, hours, self.config)
        if why is not None and self.alarms.find_active(AlarmCode.CALIBRATION_CHECK_DUE, SOURCE) is None:
            log.warning("calibration check due: %s", why)
            await self.alarms.raise_alarm(AlarmCode.CALIBRATION_CHECK_DUE, source=SOURCE, detail=why + ": run `cellctl calibrate verify`")

    async def _follow(self, queue: asyncio.Queue) -> None:  # type: ignore[type-arg]
        try:
            while True:
                try:
                    ev = await asyncio.wait_for(queue.get(), HOURS_POLL_S)
                except asyncio.TimeoutError:
                    await self.review()
                    continue
                if ev.kind == "cycle" and ev.data.get("state") == "done":
                    self.cycles_since += 1
                    await self.review()
        finally:
            self.events.unsubscribe(queue)
