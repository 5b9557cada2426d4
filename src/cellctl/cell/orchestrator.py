"""The orchestrator: PackML state actions, the cycle queue, and the records of every cycle.

It owns no devices' protocols and no transport: the API, the PLC interface and the CLI call it;
it calls the devices through their ports (:mod:`cellctl.cell.cycle`), the state machine, the
alarms and the store. Cycles run one at a time, only in Execute.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from cellctl.calibration.errors import CalibrationRefused
from cellctl.cell.alarms import AlarmManager
from cellctl.cell.cycle import run_cycle
from cellctl.cell.cycle_values import CellDevices, CycleResult
from cellctl.cell.laser_timing import LaserTiming
from cellctl.cell.observers import Pumps
from cellctl.cell.cycle_failure import CycleFailed
from cellctl.cell.events import EventHub
from cellctl.cell.final_record import FinalRecord, FinalRecords, despite_store_fault
from cellctl.cell.outcome import part_verdict, result_fields
from cellctl.cell.packml import (
    CycleStepNotAllowed,
    EventKind,
    MachineEvent,
    MachineStatus,
    PackMLMachine,
)
from cellctl.cell.quality_loop import InstallQualityLoop
from cellctl.cell.recipe_gate import calibration_status, cycle_refusal
from cellctl.cell.recorder import StoreRecorder
from cellctl.cell.robots import TrackedRobot
from cellctl.cell.sources import CalibrationSource, SimTruth
from cellctl.cell.tags import not_ready_for_cycle
from cellctl.cell.watchdog import DeviceWatchdog
from cellctl.config.feature import shot_feature
from cellctl.config.schema import CellConfig
from cellctl.config.settings_id import recipe_settings_id
from cellctl.domain import AlarmCode, CycleStep, PackMLCommand, PackMLState
from cellctl.memory import release_free_memory
from cellctl.ports import DeviceError
from cellctl.store import REQUEST_AGAIN, AsyncCellStore, CycleRecord, CycleRequest, SubmitResult

log = logging.getLogger(__name__)

PUMP_DRAIN_S = 5.0  # at the stop, the events queued so far get this long (s) to be stored (the service's step: 10 s)

# Acting states end by themselves once their action is done (PackML "SC").
_ACTING = {
    PackMLState.STARTING,
    PackMLState.STOPPING,
    PackMLState.ABORTING,
    PackMLState.HOLDING,
    PackMLState.UNHOLDING,
    PackMLState.SUSPENDING,
    PackMLState.UNSUSPENDING,
    PackMLState.RESETTING,
    PackMLState.CLEARING,
    PackMLState.COMPLETING,
}
# Entering these stops a running cycle (and the robot).
_STOP_CYCLE = {PackMLState.STOPPING, PackMLState.ABORTING, PackMLState.HOLDING, PackMLState.SUSPENDING}
# Entering these also ends the cycles queued behind it: production ends here, a Hold or Suspend only pauses it.
_DROP_QUEUED = {PackMLState.STOPPING, PackMLState.ABORTING, PackMLState.COMPLETING}
_KEEP_QUEUED = {PackMLState.EXECUTE, *_STOP_CYCLE, PackMLState.HELD, PackMLState.UNHOLDING, PackMLState.SUSPENDED,
                PackMLState.UNSUSPENDING} - _DROP_QUEUED  # a request stored as the cell left these is dropped at once


def _commands_view(st: MachineStatus) -> dict[str, Any]:
    """The commands a status allows and those an interlock holds back (with why), JSON-ready."""
    return {"allowed_commands": sorted(c.name.lower() for c in st.allowed_commands),
            "blocked_commands": {c.name.lower(): why for c, why in st.blocked_commands.items()}}


class CycleRefused(Exception):
    """A cycle request the cell cannot take now; ``reason`` says why and what to do."""

    def __init__(self, code: AlarmCode | int, reason: str) -> None:
        super().__init__(reason)
        self.code = int(code)
        self.reason = reason


class CellOrchestrator:
    """Runs the cell: PackML state actions, one cycle at a time in Execute, all of it recorded."""

    def __init__(
        self,
        *,
        config: CellConfig,
        devices: CellDevices,
        calibration: CalibrationSource,
        store: AsyncCellStore,
        machine: PackMLMachine,
        alarms: AlarmManager,
        watchdog: DeviceWatchdog | None,
        events: EventHub,
        image_dir: Path,
        truth: SimTruth | None = None,
    ) -> None:
        self.config = config
        self.robot = devices.robot if isinstance(devices.robot, TrackedRobot) else TrackedRobot(devices.robot)
        self.devices = replace(devices, robot=self.robot)
        self.calibration, self.store, self.machine, self.alarms = calibration, store, machine, alarms
        self.watchdog, self.events, self.image_dir, self.truth = watchdog, events, image_dir, truth
        self._queue: asyncio.Queue[None] = asyncio.Queue()  # nudges for the worker
        self._pending: list[int] = []  # cycles queued, in the order they came
        self._pumps = Pumps("the cell's event records")  # machine and alarm events to the store
        self._worker_task: asyncio.Task[None] | None = None
        self._cycle_task: asyncio.Task[None] | None = None
        self._recording: asyncio.Future[None] | None = None  # the finished cycle's record being written
        self._current: int | None = None
        self._busy: int | None = None  # the cycle the worker took, from then until its record is written
        self._finished: dict[int, asyncio.Event] = {}
        self._stop_reason: str | None = None
        self._shutting_down = False  # end_for_shutdown() came: no cycle is taken or started
        self._finishing = False
        self._links: dict[str, dict[str, Any]] = {}
        self._status_parts: dict[str, Callable[[], Any]] = {}
        self.quality = InstallQualityLoop(config, store, alarms, events)
        self.records = FinalRecords(store, alarms, events)  # a cycle's end, kept and retried while the store refuses it
        self._calibration_read: dict[str, Any] = {}  # the running cycle's calibration reference, once read
        self._applied_offset: dict[str, float] = {}
        self._loop_recipe: str | None = None  # the running cycle's recipe, whose closed loop its result feeds
        self.laser_timing = LaserTiming()  # the laser-to-robot latency, kept from sweep to sweep
        machine.add_guard(PackMLCommand.COMPLETE, self._complete_guard)

    def _complete_guard(self, state: PackMLState, command: PackMLCommand) -> str | None:
        """Complete ends production in a wait state: not while a cycle still moves the robot or waits its turn."""
        queued = f"queued cycles {', '.join(map(str, self._pending))}" if self._pending else ""
        if self._busy is not None:
            also = f" and {queued}" if queued else ""
            return f"cycle {self._busy} is running{also}: Complete once it has ended, or Stop or Hold it first"
        return f"{queued}: Complete once they have ended, or Stop to drop them" if queued else None

    def add_status(self, name: str, part: Callable[[], Any]) -> None:
        """Add ``name`` to every /status snapshot, from ``part()`` (e.g. the running commissioning job)."""
        self._status_parts[name] = part

    def note_link(self, name: str, state: str, **details: float) -> None:
        """A link outside the devices (the PLC) reports its state for /status and the dashboard, kept with its time
        (``since_utc``) and figures (e.g. ``silent_for_s``), so a page opened later sees what an event told."""
        report: dict[str, Any] = {"link": state, "since_utc": datetime.now(timezone.utc).isoformat(), **details}
        self._links[name] = report
        self.events.publish(name, report)

    # -- lifecycle --------------------------------------------------------------------------

    async def start(self) -> None:
        """Recover from the last run, then start the state actor, persistence and the cycle worker."""
        report = await self.store.recover()
        await self.quality.load()
        alarm_events = self.alarms.subscribe_queue()  # before the recovery alarms: their raise is stored as well
        for ended in self.alarms.restore(await self.store.unacknowledged_alarms()):  # listed until acknowledged
            await self.store.save_alarm(ended)
        for ic in report.interrupted:
            detail = f"cycle {ic.cycle_id} was interrupted in {ic.step.name.lower()}"
            if ic.install_started:
                detail += "; the install had started: check the glass by hand, it will not be repeated"
            await self.alarms.raise_alarm(AlarmCode.CYCLE_INTERRUPTED, source="cycle", detail=detail, cycle_id=ic.cycle_id)
        for q, sink in (
            (self.machine.subscribe_queue(), self._on_machine_event),
            (alarm_events, self._on_alarm_event),
        ):
            self._pumps.start(q, sink)
        self._worker_task = asyncio.create_task(self._worker())
        if self.watchdog is not None:
            await self.watchdog.start()

    async def stop(self) -> None:
        """Stop background work (a cycle still running is left as it is: the next start marks it interrupted). The worker
        and its cycle are cancelled once and waited for: the cycle's shielded clean-up runs to its end, its events pumped."""
        if self.watchdog is not None:
            await self.watchdog.stop()
        if self._cycle_task is not None:
            self._cycle_task.cancel()
        try:
            if self._worker_task is not None:
                self._worker_task.cancel()
                await asyncio.gather(self._worker_task, return_exceptions=True)
                self._worker_task = None
            if self._recording is not None:  # a finished cycle's record is written before the store closes
                await asyncio.gather(self._recording, return_exceptions=True)
            await self._pumps.stop(drain_timeout_s=PUMP_DRAIN_S)  # an acknowledgement just made is stored too
            await self.records.stop()
        finally:
            await self._pumps.stop(drain_timeout_s=0.0)

    # -- PackML state actions ----------------------------------------------------------------

    async def _on_machine_event(self, ev: MachineEvent) -> None:
        if ev.kind is not EventKind.CYCLE_STEP:  # the steps are in the cycle's record; the audit log keeps what people and faults did
            await self.records.writes.machine_event(ev, cycle_id=self._current)  # kept while the store refuses it
        state_event: dict[str, Any] = {
            "state": ev.state_after.name,
            "mode": ev.mode_after.name,
            "step": ev.step_after.name.lower(),
            "actor": ev.actor,
            "command": None if ev.command is None else ev.command.name,
        }
        if self.machine.state is ev.state_after:  # the commands of this state; a later event brings its own
            state_event.update(_commands_view(self.machine.status()))
        self.events.publish("state", state_event)
        if not ev.state_changed:
            return
        state = ev.state_after
        if state in _STOP_CYCLE:
            why = f"{ev.command.name.lower()} by {ev.actor}" if ev.command is not None else f"{ev.actor}"
            await self._stop_running_cycle(f"the cell went to {state.name.lower()} ({why})")
        if state in _DROP_QUEUED:
            await self._drop_queued(f"the cell went to {state.name.lower()} before it began")
        if state is PackMLState.RESETTING:
            self.alarms.reset_stop_reason()
        if state in _ACTING:
            if self.machine.state is state:  # nothing moved it on meanwhile
                await self.machine.state_complete(actor="system", source="cell")
        if state is PackMLState.EXECUTE:
            self._kick()

    async def _on_alarm_event(self, ev: Any) -> None:
        await self.records.writes.alarm(ev.alarm)  # kept while the store refuses it
        a = ev.alarm
        self.events.publish(
            "alarm",
            {"uid": a.uid, "code": int(a.code), "message": a.message, "active": a.active, "acknowledged": a.acknowledged},
        )

    async def _stop_running_cycle(self, reason: str) -> None:
        """Leave Execute: end the running cycle as stopped (its reason; no new motion; its task cancelled, then the
        robot's stop) and wait for its end, clean-up included. One already recording its outcome is let finish."""
        if (task := self._cycle_task) is None:
            return
        halted = not (task.done() or self._finishing or self.robot.halted)  # else recording its outcome, or stopped already
        if halted:
            self._stop_reason = reason
            self.robot.halt(reason)  # the cycle starts no motion and releases no glass from now on
            task.cancel()  # once, before the robot's stop ends the move it waits on: a second would cut its shielded
            with contextlib.suppress(DeviceError):  # clean-up loose; one 3.11's wait_for drops is met by the halt
                await self.robot.stop(timeout_s=self.config.process.motion.read_timeout_s)
        try:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        finally:
            if halted:
                self.robot.resume()

    async def end_for_shutdown(self, why: str) -> None:
        """The service is stopping (SIGTERM, Ctrl-C): no queued cycle starts any more, and a running one ends as
        stopped now (the robot stopped, its record and the PLC's answer written), not cut off half-way at the exit."""
        self._shutting_down = True
        await self._stop_running_cycle(why)

    async def _drop_queued(self, why: str) -> None:
        """End every queued cycle as failed, saying why: a Stop or Abort ends production, and a queued
        cycle must not start by itself once the cell is back in Execute, perhaps long after its requester gave up."""
        dropped, self._pending = self._pending, []
        for cid in dropped:
            reason = f"not started: {why}; in Execute, {REQUEST_AGAIN}"
            await self.store.fail_cycle(cid, error=reason, result={"error_code": self._stop_code(AlarmCode.CYCLE_STOPPED)})
            self.events.publish("cycle", {"cycle_id": cid, "state": "failed", "error": reason})
            self._ended(cid)

    # -- cycles -----------------------------------------------------------------------------

    def ready_for_cycle(self) -> bool:
        """The cell takes a cycle now: Execute (production or maintenance); it queues behind a running one."""
        return self._why_not_ready() is None

    def _why_not_ready(self) -> str | None:
        return "the service is stopping: request it again once it runs" if self._shutting_down else \
            not_ready_for_cycle(self.machine.state, self.machine.mode)

    async def submit_cycle(self, request: CycleRequest, *, scope: str, key: str, actor: str) -> SubmitResult:
        """Queue a cycle under an idempotency key; the same key returns the same cycle, never a second one.

        Raises CycleRefused, for a key it has not seen, when the cell is not in Execute or the recipe is not taught or
        not ready (its teaching or nine-point map stale, expired...: :func:`cycle_refusal`)."""
        existing = await self.store.cycle_for_key(scope, key)
        if existing is None and (why := self._why_not_ready()) is not None:
            raise CycleRefused(AlarmCode.NOT_IN_EXECUTE, why)
        refused = None if existing is not None else cycle_refusal(self.calibration, request.recipe)
        if refused is not None:
            raise CycleRefused(AlarmCode.RECIPE_NOT_TAUGHT, refused)
        result = await self.store.submit_cycle(request, scope=scope, key=key, actor=actor)
        if result.created:
            self._finished[result.cycle.id] = asyncio.Event()
            self._pending.append(result.cycle.id)
            self._kick()
            self.events.publish("cycle", {"cycle_id": result.cycle.id, "state": "queued", "part_id": request.part_id})
            if (state := self.machine.state) not in _KEEP_QUEUED:  # a Stop, Abort or Complete came while it was stored
                await self._drop_queued(f"the cell went to {state.name.lower()} before it began")
        return result

    async def wait_cycle(self, cycle_id: int, timeout_s: float) -> CycleRecord:
        """The cycle's record once it has finished (or as it is after ``timeout_s``)."""
        ev = self._finished.get(cycle_id)
        if ev is not None:
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(ev.wait(), timeout_s)
        return await self.store.cycle(cycle_id)

    def _kick(self) -> None:
        """Nudge the worker (it waits for Execute before taking the next cycle)."""
        self._queue.put_nowait(None)

    async def _worker(self) -> None:
        while True:
            await self._queue.get()
            while self._pending and self.ready_for_cycle():
                nxt = self._pending.pop(0)
                self._busy, self._finishing = nxt, False
                self._cycle_task = asyncio.create_task(self._run(nxt))
                try:
                    await self._cycle_task
                except asyncio.CancelledError:
                    task = asyncio.current_task()
                    if task is not None and task.cancelling():  # the worker itself is being stopped
                        raise
                    if self._current != nxt:  # stopped before its first step: queued again (a Stop or Abort ends it)
                        self._pending.insert(0, nxt)
                except Exception:  # noqa: BLE001 - a bug around one cycle must not stop the cell taking the next
                    log.exception("cycle %d: the worker caught a fault outside the cycle's own handling", nxt)
                finally:
                    self._cycle_task = None
                    self._busy = None if self._busy == nxt else self._busy  # its record was written, or it never began

    async def _run(self, cycle_id: int) -> None:
        self._current = cycle_id
        self._finishing = False
        clock = self.devices.clock  # the cycle is timed on one clock, even if the devices are swapped meanwhile
        rec = StoreRecorder(self.records.writes, self.machine, self.events, cycle_id, self.image_dir, clock=clock)
        started = (clock, clock(), time.monotonic())
        self._calibration_read, self._applied_offset, self._loop_recipe = {}, self.quality.no_offset(), None
        self._stop_reason = None
        result: CycleResult | None = None
        failure: tuple[str, int, AlarmCode | None] | None = None  # (reason, error code, alarm to raise)
        try:  # from its start: a stop (or a store fault) while it starts still ends it with a record
            recipe = (await self.store.start_cycle(cycle_id)).request.recipe
            self.events.publish("cycle", {"cycle_id": cycle_id, "state": "running"})
            result = await self._cycle(rec, recipe)
        except CycleFailed as f:
            # A move the stop interrupted is the stop's doing, not a robot fault of its own.
            failure = self._stopped() if self._stop_reason is not None else (str(f), int(f.code), f.code)
        except CycleStepNotAllowed:
            # A Hold, Suspend, Stop or Abort landed between two steps; what caused it is recorded.
            self._stop_reason = self._stop_reason or f"the cell left Execute ({self.machine.state.name.lower()})"
            failure = self._stopped()
        except asyncio.CancelledError:
            if self._stop_reason is None:
                raise  # shutdown: leave it running; the next start marks it interrupted
            failure = self._stopped()
        except Exception as err:  # noqa: BLE001 - any bug still ends the cycle with a record and an alarm (1703 a store fault)
            failure = self.records.writes.cycle_fault(cycle_id, err)  # logged there
        finally:
            self._finishing = True
        if failure is not None:  # a device may have been restarted or swapped: the next sweep times the laser anew
            self.laser_timing.forget(f"cycle {cycle_id} failed")
        # Recording the outcome must not be cut short by a stop arriving now (stop() waits for it).
        self._recording = asyncio.ensure_future(self._record(rec, cycle_id, started, result, failure))
        await asyncio.shield(self._recording)

    def _stopped(self) -> tuple[str, int, AlarmCode | None]:
        """A cycle the cell stopped: its reason, and as its code the first-out alarm if one caused the stop
        (the PLC and the record name the cause, e.g. 1201; the text adds its message), else that a command stopped it."""
        stop = self.alarms.stop_reason
        cause = "" if stop is None else f": alarm {int(stop.code)} {stop.message}"
        return (f"stopped: {self._stop_reason}{cause}", self._stop_code(AlarmCode.CYCLE_STOPPED), None)

    def _stop_code(self, otherwise: int) -> int:
        """The first-out alarm's code when one stopped the cell (the cause the PLC and the record name), else ``otherwise``."""
        stop = self.alarms.stop_reason
        return int(stop.code) if stop is not None else int(otherwise)

    def _ended(self, cycle_id: int) -> None:
        """Wake whoever waits for the cycle's end (``?wait=true``)."""
        ev = self._finished.pop(cycle_id, None)
        if ev is not None:
            ev.set()

    async def _cycle(self, rec: StoreRecorder, recipe: str) -> CycleResult:
        await rec.step_started(CycleStep.CALIBRATE)
        problems = self.calibration.problems(recipe)
        if problems:
            raise CycleFailed(CycleStep.CALIBRATE, AlarmCode.CALIBRATION_INVALID, "; ".join(problems))
        reference = self._calibration_read = self.calibration.reference(recipe)
        self._loop_recipe = recipe  # each recipe's installs feed its own closed loop
        self._applied_offset = self.quality.offset_for_next(recipe, reference)
        view = self.config.for_recipe(recipe)
        figures = {"calibration": reference, "install_offset": self._applied_offset, "recipe_settings": recipe_settings_id(view)}
        await rec.step_figures(CycleStep.CALIBRATE, figures)
        if self.truth is not None:
            self.truth.new_car_body(recipe)
        try:
            cal = await asyncio.to_thread(self.calibration.cycle_calibration, recipe)  # off the loop: file reads, the oracle
        except CalibrationRefused as err:  # the set changed (or was damaged) since problems() was asked
            raise CycleFailed(CycleStep.CALIBRATE, AlarmCode.CALIBRATION_INVALID, str(err)) from err
        offset = self.quality.offset_as_pose(self._applied_offset)
        return await run_cycle(
            self.devices, cal, view.process, view.vision, rec, install_offset=offset, laser_timing=self.laser_timing,
            feature=shot_feature(view),
        )  # fmt: skip

    async def _record(
        self,
        rec: StoreRecorder,
        cycle_id: int,
        started: tuple[Callable[[], float], float, float],
        result: CycleResult | None,
        failure: tuple[str, int, AlarmCode | None] | None,
    ) -> None:
        try:
            clock, on_clock, on_host = started
            elapsed = clock() - on_clock
            times = {"wall_time_s": time.monotonic() - on_host}
            if failure is None and result is not None:
                not_ok = part_verdict(result, self.config.process.tolerance)
                if not_ok is not None:  # first, so the part's alarm is the first-out cause the PLC reads
                    await self.alarms.raise_alarm(
                        AlarmCode.INSTALL_OUT_OF_TOLERANCE, source="inspection", detail=not_ok, cycle_id=cycle_id
                    )
                await despite_store_fault(rec.close_step(ok=True), f"cycle {cycle_id}'s last step")
                fields = result_fields(result, elapsed, not_ok=not_ok) | times | {"step_time_s": rec.step_times_s()}
                fields["calibration_version"] = self._calibration_read.get("version")
                fields["spc"], update = await self.quality.feed_cycle(
                    cycle_id, result.measured, recipe=self._loop_recipe, calibration_read=self._calibration_read,
                    applied=self._applied_offset,
                )  # fmt: skip
                await self.records.write(FinalRecord.done(cycle_id, fields, self._true_error(), part_ok=not_ok is None))
                if update is not None:
                    await self.quality.raise_drift(cycle_id, update, self._loop_recipe or "")
            elif failure is not None:
                reason, code, alarm = failure
                if alarm is not None:
                    # Raised before the record is written, so the record (and the PLC) carry the first-out
                    # cause: this alarm, or one that stopped the cell first (e.g. the watchdog's link lost).
                    await self.alarms.raise_alarm(alarm, source="cycle", detail=reason, cycle_id=cycle_id)
                    code = self._stop_code(code)
                await despite_store_fault(rec.close_step(ok=False, error=reason), f"cycle {cycle_id}'s last step")
                spc, _ = await self.quality.feed_cycle(
                    cycle_id, None, recipe=self._loop_recipe, calibration_read=self._calibration_read,
                    applied=self._applied_offset, failed=True,
                )  # fmt: skip
                figures = {"error_code": code, "cycle_time_s": elapsed, **times, "step_time_s": rec.step_times_s(),
                           "spc": spc, "calibration_version": self._calibration_read.get("version")}
                true_error = self._true_error() if rec.installing else None  # no glass went in: nothing to score
                await self.records.write(FinalRecord.failed(cycle_id, reason, figures, true_error))
        finally:
            self._current = self._busy = None
            with contextlib.suppress(Exception):
                await self.machine.set_cycle_step(CycleStep.NONE)
            self._ended(cycle_id)
            with contextlib.suppress(Exception):
                await asyncio.to_thread(release_free_memory)  # what the cycle's worker threads freed

    def _true_error(self) -> dict[str, float] | None:
        return None if self.truth is None else asdict(self.truth.install_error())

    # -- commands and status ------------------------------------------------------------------

    async def command(self, command: PackMLCommand, *, actor: str, source: str) -> MachineEvent:
        """A PackML command from any source (REST and dashboard, PLC, OPC UA): CommandRefused when the table forbids it
        and no taker carries it out (then the answer is a TakenCommand with its effect, e.g. a Stop in Stopped's cancelled job)."""
        return await self.machine.command(command, actor=actor, source=source)

    def status(self) -> dict[str, Any]:
        """A JSON-ready snapshot for /status and the dashboard."""
        st = self.machine.status()
        stop = self.alarms.stop_reason
        return {
            "cell_id": self.config.cell_id,
            "service_mode": self.config.mode,
            "state": st.state.name,
            "state_id": int(st.state),
            "mode": st.mode.name,
            "mode_id": int(st.mode),
            "cycle_step": st.cycle_step.name.lower(),
            "current_cycle": self._current,
            "queued_cycles": len(self._pending),
            **_commands_view(st),
            "stop_reason": None if stop is None else {"code": int(stop.code), "message": stop.message},
            "devices": {name: {"link": h.link.value, "heartbeat_age_s": h.heartbeat_age_s, "round_trip_s": h.last_round_trip_s}
                        for name, h in (self.watchdog.health().items() if self.watchdog else [])},
            "links": {name: dict(report) for name, report in self._links.items()},
            "calibration": calibration_status(self.calibration, (r.name for r in self.config.process.recipes)),
            "spc": self.quality.snapshot(),
            **{name: part() for name, part in self._status_parts.items()},
        }
