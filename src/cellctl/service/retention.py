"""Storage retention of the running cell: prune images and old records, watch the disk, report the figures.

What is kept is :class:`cellctl.config.store.RetentionConfig` ([store.retention]):

- **images** first: a pass deletes the oldest image files while they are older than
  ``images_days`` or all images together exceed ``images_max_gb`` (images of a queued or running
  cycle are never touched). The image's reference in its cycle record stays, saying when and why
  the file was pruned. A pass runs every ``period_s`` and, when a finished cycle brings the
  images near their bound, right after that cycle; it leaves room under the bound for the next
  cycle's images (the most one of the last few cycles wrote, :func:`cycle_headroom`), so the
  folder stays under the bound between passes too. A reference whose file is not there is marked
  missing (never deleted for it; kept again when the file is back); a folder that is not there,
  unreadable, or holds none of the finished cycles' files looks unmounted: the images are left alone.
- **cycle records** (steps, image references, idempotency keys; refused requests' keys too) after ``cycles_days``, and
  **alarm records** after ``alarms_days`` (inactive, acknowledged, of no kept cycle); each deletion of records is
  written to the audit log.
- pruning by **age** is held while the wall clock is in doubt (:mod:`cellctl.service.retention_clock`: stepped
  since the last pass, or far ahead of the newest record), said in the log and ``last_error``; by size it goes on;
  after a hold that ended by confirming the clock, records from before it are aged without the gap for one period.
  Cycle records and their images are aged from the cycle's end stamp, which never goes back, so those made while the
  clock was set back keep their true age after it is right again, restarts included.
- the **audit log** is never pruned. It is append-only and hash-chained from its first entry
  (the database refuses deletes, :meth:`cellctl.store.CellStore.verify_audit_chain` checks
  that no entry is missing), it is the record of who commanded what, and it is small beside the
  images (a few hundred bytes per command or state change). Pruning it would mean exporting
  whole segments with a signed anchor first; until that exists, the disk-space alarms guard it.

The disk check runs every ``disk_check_period_s`` on the file systems of the database and the
images: below ``disk_warn_free_gb`` free it raises :attr:`AlarmCode.DISK_SPACE_LOW` (a warning),
below ``disk_stop_free_gb`` :attr:`AlarmCode.DISK_SPACE_CRITICAL`, whose reaction (Hold) stops
production while records can still be written. That alarm waits while the robot installs a
glass (the install step writes almost nothing; stopping it halfway would leave the glass
unfinished) and is raised as soon as the step ends. Both are conditions: they clear when the
free space is back above their threshold (plus a margin, so they do not flap). A file system
that cannot be measured makes ``disk`` "unknown" (with no free figure when none answered) and is
named with its cause in ``last_error``: the alarms cannot guard it until it answers again.

:meth:`StorageRetention.status` is the ``storage`` part of /status (cached figures of the last
pass or check, never a scan per request).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import shutil
import time
from collections.abc import Callable
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.events import EventHub
from cellctl.config.store import RetentionConfig, days_or_none
from cellctl.domain import AlarmCode, CycleStep
from cellctl.service.retention_clock import ClockGuard
from cellctl.service.retention_disk import DiskReading, read_free
from cellctl.service.retention_figures import Figures, PassReport, clear_at, iso_utc
from cellctl.service.retention_plan import (
    GB,
    MB,
    ORPHAN_GRACE_S,
    FileInfo,
    ImageFolderUnavailable,
    ImagePlan,
    cycle_headroom,
    largest_cycle_in_names,
    looks_unmounted,
    plan_images,
    scan_images,
    storable,
    unlink_all,
)
from cellctl.store import AsyncCellStore, KeptImage
from cellctl.store.retention import MISSING_REASON

log = logging.getLogger(__name__)

DEFERRED_CHECK_S = 0.5  # how often the disk check looks again while the stop alarm waits for an install
NEAR_BOUND = 0.9  # a finished cycle triggers a pass when the images reach this share of their target
ALARM_SOURCE = "storage"


def _utcnow() -> datetime:
    return datetime.now(timezone.utc)


class StorageRetention:
    """The background task: :meth:`start` after the store opened, :meth:`stop` before it closes.

    Args:
        config: [store.retention].
        store: the cell's store (its queries run on the store's thread).
        alarms: raises and clears the disk-space alarms.
        image_dir: where the recorder writes the cycle images.
        db_path: the database file (its -wal and -shm files count too).
        events: the cell's event hub; a finished cycle may trigger a pass.
        cycle_step: the cycle step running now (the stop alarm waits out INSTALL).
        clock: UTC wall clock (ages of images and records; held while in doubt, :mod:`.retention_clock`).
        monotonic: the monotonic clock the wall clock is checked against between passes.
        disk_usage: ``shutil.disk_usage`` (tests give a fake).
        mqtt_results: MQTT publication is on: keep cycles whose result is not queued yet (else count them dropped).
    """

    def __init__(
        self,
        config: RetentionConfig,
        store: AsyncCellStore,
        alarms: AlarmManager,
        *,
        image_dir: Path,
        db_path: Path,
        events: EventHub | None = None,
        cycle_step: Callable[[], CycleStep] = lambda: CycleStep.NONE,
        clock: Callable[[], datetime] = _utcnow,
        disk_usage: Callable[[Path], Any] = shutil.disk_usage,
        mqtt_results: bool = False,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.config = config
        self.store = store
        self.alarms = alarms
        self.image_dir = image_dir
        self.db_path = db_path
        self.events = events
        self._cycle_step = cycle_step
        self._clock = clock
        self._monotonic = monotonic
        self._guard = ClockGuard()
        self._newest: tuple[int, datetime] | None = None  # the newest cycle record the last pass saw
        self._disk_usage = disk_usage
        self.mqtt_results = mqtt_results
        self._fig = Figures()
        self._totals = PassReport()  # every pass since start, summed
        self._task: asyncio.Task[None] | None = None
        self._wake = asyncio.Event()
        self._lock = asyncio.Lock()
        self._queue: asyncio.Queue[Any] | None = None
        self._failures = 0
        self._headroom = 0  # bytes a pass leaves free under the image bound for the next cycle's images
        self._odd_names: set[str] = set()  # files whose names are not UTF-8, logged once each

    # -- lifecycle ----------------------------------------------------------------------------

    async def start(self) -> None:
        """A first disk check now (so /status has figures at once), then the background task, whose
        first pass runs at once (a backlog of old images must not hold up the service's start)."""
        if self._task is not None:
            return
        await self._guarded("disk check", self.check_disk)
        if self.events is not None:
            self._queue = self.events.subscribe()
        self._task = asyncio.create_task(self._loop(), name="cellctl-retention")

    async def stop(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        if self._queue is not None and self.events is not None:
            self.events.unsubscribe(self._queue)
            self._queue = None

    def trigger(self) -> None:
        """Ask for an image check soon (e.g. after a cycle wrote its images)."""
        self._wake.set()

    # -- figures ------------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """The ``storage`` part of /status (as of the last pass or disk check)."""
        f, c = self._fig, self.config
        mb = lambda b: None if b is None else round(b / MB, 3)  # noqa: E731
        return {
            "images_mb": mb(f.images_bytes),
            "images_count": f.images_count,
            "oldest_image_utc": iso_utc(f.oldest_image),
            "database_mb": mb(f.database_bytes),
            "free_disk_gb": None if f.free_bytes is None else round(f.free_bytes / GB, 3),
            "disk": f.disk,  # ok | low | critical | unknown
            "checked_utc": iso_utc(f.disk_checked),
            "last_pass_utc": iso_utc(f.last_pass),
            "last_error": "; ".join(e for e in (f.images_problem, f.disk_problem, self.clock_hold, f.last_error) if e) or None,
            "pruned_since_start": {
                "images": self._totals.images_pruned, "orphan_files": self._totals.orphans_deleted,
                "cycles": self._totals.cycles_deleted, "alarms": self._totals.alarms_deleted,
            },  # fmt: skip
            "retention": {
                "enabled": c.enabled, "images_days": c.images_days, "images_max_gb": c.images_max_gb,
                "cycles_days": c.cycles_days, "alarms_days": c.alarms_days, "audit_log": "kept (never pruned)",
                "disk_warn_free_gb": c.disk_warn_free_gb, "disk_stop_free_gb": c.disk_stop_free_gb,
            },  # fmt: skip
        }

    @property
    def clock_hold(self) -> str | None:
        """Why pruning by age is held now (the wall clock is in doubt), with the fix; None while it is not."""
        held = self._guard.held
        return held and f"retention: {held}: pruning by age held; {self._guard.advice}"

    def database_bytes(self) -> int:
        """The database's files on disk: the file, its write-ahead log and shared memory."""
        total = 0
        for suffix in ("", "-wal", "-shm"):
            with contextlib.suppress(OSError):
                total += os.stat(f"{self.db_path}{suffix}").st_size
        return total

    # -- the disk -----------------------------------------------------------------------------

    def _read_disk(self) -> DiskReading:
        """The least free space of the file systems holding the database and the images, and those that failed."""
        return read_free([("database", self.db_path.parent), ("images", self.image_dir)], self._disk_usage)

    async def check_disk(self) -> str:
        """Measure the free space; raise or clear the disk-space alarms. Returns ok, low, critical or unknown
        (a file system not measured); raises OSError, naming each path and its cause, when none was."""
        reading = await asyncio.to_thread(self._read_disk)
        self._fig.disk_checked = self._clock()
        self._fig.database_bytes = await asyncio.to_thread(self.database_bytes)
        if reading.free is None or reading.where is None:
            self._fig.free_bytes, self._fig.free_path, self._fig.disk = None, None, "unknown"
            self._fig.deferred, self._fig.disk_problem = False, None  # the error goes to last_error (_guarded)
            raise OSError(reading.unread())
        free, where = reading.free, reading.where
        c = self.config
        warn, stop = c.disk_warn_free_gb * GB, c.disk_stop_free_gb * GB
        level = "critical" if free < stop else "low" if free < warn else "ok"
        detail = f"{free / GB:.2f} GB free on {where}"
        await self._condition(AlarmCode.DISK_SPACE_LOW, free < warn, free > clear_at(warn),
                              f"{detail} (below {c.disk_warn_free_gb:g} GB)")  # fmt: skip
        deferred = False
        if free < stop and self.alarms.find_active(AlarmCode.DISK_SPACE_CRITICAL, ALARM_SOURCE) is None:
            if self._cycle_step() is CycleStep.INSTALL:
                deferred = True  # raised once the install step ends (checked every DEFERRED_CHECK_S)
                if not self._fig.deferred:
                    log.warning("disk space critical (%s); the stop alarm waits for the install step to end", detail)
        if not deferred:
            await self._condition(AlarmCode.DISK_SPACE_CRITICAL, free < stop, free > clear_at(stop),
                                  f"{detail} (below {c.disk_stop_free_gb:g} GB)")  # fmt: skip
        self._fig.deferred = deferred
        self._fig.disk_problem = reading.problem()
        if reading.failed and level == "ok":
            level = "unknown"  # the file system not measured may be the full one
        self._fig.free_bytes, self._fig.free_path, self._fig.disk = free, where, level
        return level

    async def _condition(self, code: AlarmCode, raise_it: bool, clear_it: bool, detail: str) -> None:
        active = self.alarms.find_active(code, ALARM_SOURCE)
        if raise_it and active is None:
            log.warning("%s: %s", code.name.lower(), detail)
            await self.alarms.raise_alarm(code, source=ALARM_SOURCE, detail=detail)
        elif clear_it and active is not None:
            log.info("%s cleared: %s", code.name.lower(), detail)
            self.alarms.clear(code, source=ALARM_SOURCE)

    # -- a pass -------------------------------------------------------------------------------

    async def run_once(self) -> PassReport:
        """One pass: images, then cycle records, then alarm records (nothing when disabled); the figures after it."""
        async with self._lock:
            t0 = time.monotonic()
            report = PassReport()
            now = self._clock()
            c = self.config
            by_age = c.enabled and await self._clock_trusted(now)
            kept = await self.store.kept_images()
            files = await self._scan_for_pass(kept)
            if files is not None:  # None: the folder looks unmounted; no image is pruned, none marked missing
                await self._images(kept, files, report, now, by_age=by_age)
            if by_age:
                report.cycles_deleted = await self._prune_cycles(now)
                report.alarms_deleted = await self._prune_alarms(now)
            self._fig.last_pass = now
            self._fig.database_bytes = await asyncio.to_thread(self.database_bytes)
            report.seconds = time.monotonic() - t0
            self._totals.add(report)
            if report.images_pruned or report.cycles_deleted or report.alarms_deleted or report.orphans_deleted:
                # Images go after almost every cycle once the bound is reached: that is debug; records are news.
                log.log(
                    logging.INFO if report.cycles_deleted or report.alarms_deleted else logging.DEBUG,
                    "retention: pruned %d images, %d orphan files, %d cycle records, %d alarm records in %.2f s",
                    report.images_pruned, report.orphans_deleted, report.cycles_deleted, report.alarms_deleted,
                    report.seconds,
                )  # fmt: skip
            return report

    async def _clock_trusted(self, now: datetime) -> bool:
        """Whether the wall clock may age records in this pass (:class:`ClockGuard`); a hold is logged as it starts and ends."""
        g, c, was = self._guard, self.config, self._guard.held
        self._newest = await self.store.newest_cycle()
        trusted = self._newest if g.trusted_id is None else await self.store.newest_cycle(at_most_id=g.trusted_id)
        periods = [d for d in (c.images_days, days_or_none(c.cycles_days), days_or_none(c.alarms_days)) if d is not None]
        held = g.review(now, self._monotonic(), self._newest, trusted, periods)
        if held and not was:
            log.warning("%s (images over their size bound still go)", self.clock_hold)
        elif was and not held:
            log.info("retention: %s; pruning by age resumes", g.note)
        return held is None

    async def _images(
        self, kept: list[KeptImage], files: dict[str, FileInfo], report: PassReport, now: datetime, *, by_age: bool
    ) -> None:
        """The image part of a pass (only measuring when disabled; by size only while the clock is in doubt)."""
        c = self.config
        kept, leftovers = await self._reconcile(kept, files, report)
        files = {n: f for n, f in files.items() if n not in leftovers}
        if c.enabled:
            self._headroom = cycle_headroom(kept, files, int(c.images_max_gb * GB))
            target = int(c.images_max_gb * GB) - self._headroom
            plan = plan_images(
                kept, files, now=self._guard.cutoff(now, c.images_days) + timedelta(days=c.images_days),
                images_days=c.images_days if by_age else None, max_bytes=target,
                stated_bound=int(c.images_max_gb * GB), orphan_grace_s=ORPHAN_GRACE_S if by_age else math.inf,
            )  # fmt: skip
            await self._apply(plan, sorted(leftovers), report, now)
        else:
            plan = plan_images(kept, files, now=now, images_days=None, max_bytes=None)
        self._fig.images_bytes, self._fig.images_count = plan.kept_bytes, plan.kept_count
        self._fig.oldest_image, self._fig.images_checked = plan.oldest_kept, now

    async def _scan_for_pass(self, kept: list[KeptImage]) -> dict[str, FileInfo] | None:
        """The image files, or None when the folder looks unmounted or moved (said in /status)."""
        try:
            files = await asyncio.to_thread(scan_images, self.image_dir)
            why = looks_unmounted(kept, files)
            why = why and f"the image folder {self.image_dir}: {why}"
        except ImageFolderUnavailable as err:
            files, why = {}, (str(err) if kept else None)  # no reference yet: nothing there to lose
        if why:
            why = (f"images: {why}; it looks unmounted or moved: mount it again (or give the service read access "
                   "to it); until then retention prunes no image and marks none missing")  # fmt: skip
            if why != self._fig.images_problem:
                log.warning("retention: %s", why)
        elif self._fig.images_problem:
            log.info("retention: the image folder %s is back", self.image_dir)
        self._fig.images_problem = why
        return None if why else files

    async def _reconcile(
        self, kept: list[KeptImage], files: dict[str, FileInfo], report: PassReport
    ) -> tuple[list[KeptImage], set[str]]:
        """The kept references after those marked missing whose file is back are kept again, and the
        leftovers: files whose references all say retention pruned them (a crash between mark and unlink)."""
        referenced = {k.uri for k in kept}
        unreferenced = []
        for name in (n for n in files if n not in referenced):
            if storable(name):
                unreferenced.append(name)
            elif name not in self._odd_names:  # no record can name it: an orphan file like any other
                self._odd_names.add(name)
                log.warning("retention: %r in %s: the name is not UTF-8, so no cycle record names it; it is "
                            "treated as an orphan file (rename it, or move it out of the folder to keep it)",
                            os.fsencode(name), self.image_dir)  # fmt: skip
        if unreferenced and self.config.enabled:
            back = await self.store.restore_missing_images(unreferenced)
            if back:
                report.images_restored = len(back)
                log.info("retention: %d image files marked missing are back; their references are kept again",
                         len(back))  # fmt: skip
                kept = await self.store.kept_images()
                restored = set(back)
                unreferenced = [n for n in unreferenced if n not in restored]
        return kept, (await self.store.pruned_only(unreferenced) if unreferenced else set())

    async def _apply(self, plan: ImagePlan, leftovers: list[str], report: PassReport, now: datetime) -> None:
        if plan.missing:  # only marked, never deleted for it: a file that is back gets its reference back
            report.images_missing = await self.store.mark_images_pruned(plan.missing, reason=MISSING_REASON, at=now)
        # Mark first, then delete: a crash in between leaves a file the next pass deletes, never a
        # reference that claims an image which is gone without saying so.
        for reason, names in plan.prune.items():
            report.images_pruned += await self.store.mark_images_pruned(names, reason=reason, at=now)
        names = [n for ns in plan.prune.values() for n in ns]
        await asyncio.to_thread(unlink_all, self.image_dir, [*names, *leftovers])
        report.orphans_deleted = await asyncio.to_thread(unlink_all, self.image_dir, plan.orphans)

    async def _prune_cycles(self, now: datetime) -> int:
        days = days_or_none(self.config.cycles_days)
        if days is None:
            return 0
        cutoff = self._guard.cutoff(now, days)  # less an idle gap the clock was in doubt over (.retention_clock)
        deleted: list[int] = []
        hwm = None if self.mqtt_results else (await self.store.outbox_counts()).result_hwm
        while True:
            ids, uris = await self.store.prune_cycles(created_before=cutoff, keep_unpublished=self.mqtt_results)
            if not ids:
                break
            deleted += ids
            if uris:
                await asyncio.to_thread(unlink_all, self.image_dir, uris)
            await asyncio.sleep(0)  # let the cycle's own writes in between batches
        unpublished = 0 if hwm is None else sum(i > hwm for i in deleted)
        if unpublished:
            log.warning("retention: deleted %d cycles whose MQTT result was never queued ([mqtt] enabled = false): "
                        "counted as dropped results; enable [mqtt] or raise cycles_days to publish them", unpublished)
        if deleted:
            await self.store.append_audit(
                actor="system", source="retention", action="retention.prune_cycles",
                params={"cycles": len(deleted), "first_id": min(deleted), "last_id": max(deleted),
                        "created_before": cutoff.isoformat(), "cycles_days": days, "unpublished_results": unpublished},
            )  # fmt: skip
        await self._prune_request_keys(cutoff, days)
        return len(deleted)

    async def _prune_request_keys(self, cutoff: datetime, days: float) -> None:
        """The finished idempotency keys of no cycle (a refused request's) older than the cycles' cutoff."""
        n = 0
        while k := await self.store.prune_request_keys(created_before=cutoff):
            n += k
            await asyncio.sleep(0)  # let the cycle's own writes in between batches
        if n:
            await self.store.append_audit(actor="system", source="retention", action="retention.prune_request_keys",
                                          params={"keys": n, "created_before": cutoff.isoformat(), "cycles_days": days})

    async def _prune_alarms(self, now: datetime) -> int:
        days = days_or_none(self.config.alarms_days)
        if days is None:
            return 0
        cutoff = self._guard.cutoff(now, days)
        n = await self.store.prune_alarms(raised_before=cutoff)
        if n:
            await self.store.append_audit(
                actor="system", source="retention", action="retention.prune_alarms",
                params={"alarms": n, "raised_before": cutoff.isoformat(), "alarms_days": days},
            )  # fmt: skip
        return n

    async def _scan_only(self) -> None:
        """After a cycle: measure the images (a folder scan in a worker thread); a pass if near the bound."""
        try:
            files = await asyncio.to_thread(scan_images, self.image_dir)
        except ImageFolderUnavailable:
            return  # the next pass says so in /status
        total = sum(f.size for f in files.values())
        self._fig.images_bytes, self._fig.images_count = total, len(files)
        bound = int(self.config.images_max_gb * GB)
        room = max(self._headroom, min(largest_cycle_in_names(files), bound // 2))
        if self.config.enabled and total >= NEAR_BOUND * (bound - room):
            await self._guarded_pass()

    # -- the loop -----------------------------------------------------------------------------

    async def _guarded(self, what: str, fn: Callable[[], Any]) -> None:
        """Run one step; a failure is logged (with its trace the first time only) and reported in /status."""
        try:
            await fn()
        except asyncio.CancelledError:
            raise
        except Exception as err:  # noqa: BLE001 - the task must outlive a failed pass; the next one retries
            self._failures += 1
            self._fig.last_error = f"{what}: {type(err).__name__}: {err}"
            log.warning("retention %s failed: %s", what, err, exc_info=self._failures == 1)
        else:
            if self._fig.last_error and self._fig.last_error.startswith(what):
                self._fig.last_error = None

    async def _guarded_pass(self) -> None:
        await self._guarded("pass", self.run_once)

    async def _loop(self) -> None:
        c = self.config
        next_pass = time.monotonic()  # the first pass at once
        next_disk = time.monotonic() + (DEFERRED_CHECK_S if self._fig.deferred else c.disk_check_period_s)
        watcher = asyncio.create_task(self._watch_cycles()) if self._queue is not None else None
        try:
            while True:
                timeout = max(0.0, min(next_pass, next_disk) - time.monotonic())
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), timeout)
                now = time.monotonic()
                if self._wake.is_set():
                    self._wake.clear()
                    await self._guarded("scan", self._scan_only)
                    await self._guarded("disk check", self.check_disk)
                    next_disk = now + (DEFERRED_CHECK_S if self._fig.deferred else c.disk_check_period_s)
                if now >= next_pass:
                    await self._guarded_pass()
                    next_pass = time.monotonic() + c.period_s
                if now >= next_disk:
                    await self._guarded("disk check", self.check_disk)
                    next_disk = time.monotonic() + (DEFERRED_CHECK_S if self._fig.deferred else c.disk_check_period_s)
        finally:
            if watcher is not None:
                watcher.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await watcher

    async def _watch_cycles(self) -> None:
        assert self._queue is not None
        while True:
            ev = await self._queue.get()
            if ev.kind == "cycle" and ev.data.get("state") in ("done", "failed"):
                self._wake.set()

