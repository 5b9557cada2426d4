"""Commissioning jobs: calibration, teaching and verification run by the service, one at a time.

A job may start only while the cell stands in PackML **Stopped** or **Idle** (in any unit mode):
no cycle can run then (cycles run only in Execute), and while the job runs Start is refused, so
none can begin. Stop or Abort (from the dashboard, the PLC or an alarm's reaction) cancels the
job, as the engineer's cancel does: the robot is told to stop at once, the job ends
``cancelled`` with the samples it collected written as a partial dataset, and the calibration
set in use stays as it was. In Stopped, where the state table has no Stop, a Stop is taken while a
job runs or starts (a taker on the machine): it cancels the job and the cell stays Stopped. Every
move of a job runs at the procedure's reduced speed. While the watchdog has a device the procedure
uses lost (``registry.DEVICES_USED``), its job and its plan are refused before anything is asked or moved.

A job that collected its dataset computes it off the event loop; a result that passes its gates
becomes a new version of the calibration set, a refused one leaves the set unchanged and says
why. Every start, answer and cancel is in the audit log with who did it and from where.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Mapping
from dataclasses import replace
from datetime import datetime, timezone
from typing import Any

from cellctl.calibration.calibration_set import CalibrationSet, CalibrationStore, command, parts_of, recipe_named
from cellctl.calibration.compute import Outcome
from cellctl.calibration.dataset import Dataset, default_dataset_dir
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.readiness import check_ready
from cellctl.calibration.recording import record
from cellctl.cell.alarms import AlarmManager
from cellctl.cell.cancel import to_the_end
from cellctl.cell.cycle_values import CellDevices
from cellctl.cell.events import EventHub
from cellctl.cell.packml import PackMLMachine, TakenAction
from cellctl.cell.robots import ReducedSpeedRobot
from cellctl.commissioning.context import JobContext, Witness, describe_source
from cellctl.commissioning.job_end import ended_by, keep_what_was_collected, say_where_the_robot_was_left
from cellctl.commissioning.job_run import RunningJob, calibration_in_use, config_for, way_to_a_job
from cellctl.commissioning.plans import MotionPlan, PlanError
from cellctl.commissioning.procedures import Procedure
from cellctl.commissioning.prompts import Answer, Prompt, PromptDesk
from cellctl.commissioning.recovery import recover_jobs
from cellctl.commissioning.registry import ALL_PROCEDURES, JobRefused, check_links, check_options, motion_settings
from cellctl.commissioning.schedule import VerifySchedule
from cellctl.config.schema import CellConfig
from cellctl.domain import AlarmCode, MachineEvent, PackMLCommand, PackMLState
from cellctl.geometry.pose import Pose
from cellctl.memory import release_free_memory
from cellctl.ports import DeviceError, Frame
from cellctl.store import AsyncCellStore, JobRecord

log = logging.getLogger(__name__)

JOB_STATES_ALLOWED = frozenset({PackMLState.STOPPED, PackMLState.IDLE})
"""A job may start (and keeps running) only in these PackML states."""
_CANCELLING_STATES = frozenset({PackMLState.STOPPING, PackMLState.ABORTING})
PROGRESS_PERSIST_EVERY = 10
LAST_FRAMES_KEPT = 4


class JobManager:
    """Runs commissioning jobs on the service's devices.

    Args:
        config: the cell configuration.
        devices: the service's three ports (the same objects cycles use).
        calibration_store: the versioned calibration set's folder.
        store: the cell's database (job rows and the audit log).
        machine: the PackML state machine (Start is guarded while a job runs).
        alarms: raises the drift alarm of a failed verification.
        events: where job, progress and prompt events go.
        witness: the twin's truth for dataset manifests (simulated cell only).
        call_timeout_s: the timeout of the robot stop on cancel.
    """

    def __init__(
        self,
        *,
        config: CellConfig,
        devices: CellDevices,
        calibration_store: CalibrationStore,
        store: AsyncCellStore,
        machine: PackMLMachine,
        alarms: AlarmManager,
        events: EventHub,
        witness: Witness | None = None,
        call_timeout_s: float = 5.0,
    ) -> None:
        self.config = config
        self.devices = devices
        self.calibration_store = calibration_store
        self.store = store
        self.machine = machine
        self.alarms = alarms
        self.events = events
        self.witness = witness
        self.call_timeout_s = call_timeout_s
        self.desk = PromptDesk(events.publish)
        self._running: RunningJob | None = None
        self._finished: dict[int, asyncio.Event] = {}
        self._pump: asyncio.Task[None] | None = None
        self._lock = asyncio.Lock()
        self._starting: str | None = None  # a job between its state check and its start: Start is held back meanwhile
        self._last_frames: dict[int, Frame] = {}
        self.schedule: VerifySchedule | None = None
        self._halts: set[asyncio.Task[None]] = set()  # cancels a Stop began: they finish even if its caller gives up
        machine.add_guard(PackMLCommand.START, self._start_guard)
        machine.add_taker(PackMLCommand.STOP, self._stop_taker)

    # -- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
        """Recover the jobs a dead process left running (:mod:`.recovery`); follow the state machine; keep the check schedule."""
        await recover_jobs(self.store, self.calibration_store)
        queue = self.machine.subscribe_queue()
        self._pump = asyncio.create_task(self._follow(queue))
        self.schedule = VerifySchedule(self.config.calibration.procedure.verify, self.store, self.alarms, self.events,
                                       await self._last_check())  # fmt: skip
        await self.schedule.start()

    async def _last_check(self) -> datetime | None:
        """When the hand-eye was last checked and found in place (a passed verify), or calibrated."""
        for rec in await self.store.jobs(limit=500, procedure="verify"):
            if rec.state == "done" and (rec.result or {}).get("quality", {}).get("passed") and rec.finished_at is not None:
                return rec.finished_at
        try:
            cal = await asyncio.to_thread(self.current_calibration)
        except JobRefused as err:  # a damaged set: the service still starts, with alarm 1305 (cellctl.calibration.source)
            log.warning("the check schedule starts without the hand-eye's date: %s", err)
            return None
        part = None if cal is None else cal.part("hand_eye")
        return None if part is None else part.calibrated_utc

    async def stop(self) -> None:
        """Cancel a running job (the service is stopping) and stop following the machine."""
        if self.schedule is not None:
            await self.schedule.stop()
        if self._running is not None:
            with contextlib.suppress(Exception):
                await self.cancel(self._running.record.id, actor="system", source="service", reason="the service is stopping")
        if self._pump is not None:
            self._pump.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._pump
            self._pump = None

    async def _follow(self, queue: asyncio.Queue[MachineEvent]) -> None:
        while True:
            ev = await queue.get()
            if not ev.state_changed or ev.state_after not in _CANCELLING_STATES:
                continue
            run = self._running
            if run is None and self._starting is not None:  # a job between its state check and its start
                async with self._lock:
                    run = self._running
            if run is None:
                continue
            cmd = ev.command.name.lower() if ev.command is not None else "a state change"
            with contextlib.suppress(Exception):
                await self.cancel(run.record.id, actor=ev.actor, source=ev.source,
                                  reason=f"the cell went to {ev.state_after.name.lower()} ({cmd} by {ev.actor})")  # fmt: skip

    def _start_guard(self, state: PackMLState, command: PackMLCommand) -> str | None:
        run = self._running
        if run is None:
            return None if self._starting is None else f"a commissioning job ({self._starting}) is starting: wait for it or cancel it"
        return f"commissioning job {run.record.id} ({run.record.procedure}) is running: wait for it or cancel it first"

    def _stop_taker(self, state: PackMLState, command: PackMLCommand) -> TakenAction | None:
        """A Stop in Stopped (no edge there) while a job runs or starts: it cancels the job, the cell stays Stopped.
        (In Idle, Stop's edge to Stopping cancels it: :meth:`_follow`.)"""
        run = self._running
        if state not in JOB_STATES_ALLOWED or (run is None and self._starting is None):
            return None

        async def cancel_the_job(actor: str, source: str) -> str:
            return await self._cancel_on_stop(run, state, actor=actor, source=source)

        return cancel_the_job

    async def _cancel_on_stop(self, run: RunningJob | None, state: PackMLState, *, actor: str, source: str) -> str:
        """Cancel the job for a taken Stop; answer once the robot was told to stop (the job ends in its own time)."""
        if run is None:  # it was starting: it has started (or been refused) once the submit lock is free
            async with self._lock:
                run = self._running
            if run is None:
                return "the commissioning job that was starting did not start: nothing to cancel"
        rec = run.record
        if run.cancel_reason is not None:
            return f"commissioning job {rec.id} ({rec.procedure}) was already being cancelled ({run.cancel_reason})"
        halt = asyncio.create_task(self._halt(run, actor=actor, source=source,
                                              reason=f"stop by {actor} in {state.name.lower()}"))  # fmt: skip
        self._halts.add(halt)
        halt.add_done_callback(self._halts.discard)
        await asyncio.shield(halt)
        return (f"cancelled commissioning job {rec.id} ({rec.procedure}): the robot was told to stop; "
                f"the job ends cancelled with what it collected, the cell stays {state.name.title()}")  # fmt: skip

    # -- queries --------------------------------------------------------------------------------

    def running(self) -> JobRecord | None:
        return None if self._running is None else self._running.record

    def status(self) -> dict[str, Any] | None:
        """The running job for /status: id, procedure, state, progress, the open prompt's kind."""
        run = self._running
        if run is None:
            return None
        prompts = self.desk.open_prompts(run.record.id)
        return {"id": run.record.id, "procedure": run.record.procedure, "state": run.record.state, "progress": run.progress,
                "prompt": prompts[0].kind.value if prompts else None}  # fmt: skip

    def latest_frame(self, job_id: int) -> Frame | None:
        """The last frame a job grabbed (the running one's, or one of the last few jobs')."""
        run = self._running
        return run.frame if run is not None and run.record.id == job_id else self._last_frames.get(job_id)

    async def job(self, job_id: int) -> JobRecord:
        run = self._running
        if run is not None and run.record.id == job_id:
            return run.record
        return await self.store.job(job_id)

    def live(self, job_id: int) -> dict[str, Any]:
        """What only the running job has: its open prompt, progress and the live image's sequence number."""
        run = self._running
        prompts = [p.as_dict() for p in self.desk.open_prompts(job_id)]
        if run is None or run.record.id != job_id:
            return {"running": False, "prompt": prompts[0] if prompts else None, "frames": int(job_id in self._last_frames)}
        return {"running": True, "prompt": prompts[0] if prompts else None, "progress": run.progress, "frames": run.frames}

    async def wait(self, job_id: int, timeout_s: float) -> JobRecord:
        ev = self._finished.get(job_id)
        if ev is not None:
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(ev.wait(), timeout_s)
        return await self.job(job_id)

    def current_calibration(self) -> CalibrationSet | None:
        """The set in use (None before the first calibration); a damaged one is JobRefused saying how to restore it."""
        return calibration_in_use(self.calibration_store)

    # -- plans ----------------------------------------------------------------------------------

    async def plan(self, procedure: str, options: Mapping[str, Any]) -> MotionPlan:
        """The plan a job would follow now (nothing moves): poses, reach, rotation spread, robot time."""
        opts = check_options(procedure, options, self.config)
        check_links(procedure, self.alarms)  # a plan for a device known lost would be followed by a refused job
        start = await self._robot_pose()
        cal = await asyncio.to_thread(self.current_calibration)
        try:
            return await asyncio.to_thread(ALL_PROCEDURES[procedure].plan, config_for(self.config, opts), cal, opts, start,
                                         self.calibration_store.root)
        except (PlanError, CalibrationRefused) as err:
            raise JobRefused(str(err)) from None

    async def _robot_pose(self) -> Pose | None:
        try:
            return (await self.devices.robot.read_pose(timeout_s=self.call_timeout_s)).to_matrix()
        except DeviceError:
            return None

    # -- start, cancel, answer ------------------------------------------------------------------

    async def submit(self, procedure: str, options: Mapping[str, Any], *, actor: str, source: str) -> JobRecord:
        """Start a job now; refused when another job runs, the cell is not in Stopped or Idle, or a device it uses is lost."""
        opts = check_options(procedure, options, self.config)
        async with self._lock:
            if self._running is not None:
                r = self._running.record
                raise JobRefused(f"job {r.id} ({r.procedure}) is running: one job at a time; wait, or cancel it (Ctrl-C in its cellctl, the dashboard, POST /jobs/{r.id}/cancel)", conflict=True)  # fmt: skip
            state = self.machine.state
            if state not in JOB_STATES_ALLOWED:
                raise JobRefused(
                    f"the cell is {state.name}: commissioning jobs run in STOPPED or IDLE only (no cycle can run then); "
                    + way_to_a_job(state),
                    conflict=True,
                )
            check_links(procedure, self.alarms)  # before any prompt or move: a device it uses is known lost
            self._starting = procedure  # from here a Start waits: no cycle may begin beside the job
            try:
                run = await self._create(procedure, opts, actor=actor, source=source)
            finally:
                self._starting = None
        self._publish(run)
        return run.record

    async def _create(self, procedure: str, opts: dict[str, Any], *, actor: str, source: str) -> RunningJob:
        """The job's record and task, once its procedure's parts are calibrated (under the submit lock)."""
        cal = await asyncio.to_thread(self.current_calibration)
        first = self.config.default_recipe
        slot = None if cal is None else parts_of(cal, opts.get("recipe"), first)
        missing = [n for n in ALL_PROCEDURES[procedure].needs if cal is None or not cal.usable(n, slot)]
        if missing:
            named = recipe_named(slot, opts.get("recipe"), first)
            of = "" if named is None else f" (recipe {named})"
            run = "; ".join(f"`{command(n, named)}`" for n in missing)
            raise JobRefused(f"{procedure}{of} needs {', '.join(missing)} calibrated first: run {run}", conflict=True)
        rec = await self.store.create_job(
            procedure, actor=actor, source=source, options=opts, version_before=None if cal is None else cal.version
        )
        run = RunningJob(rec)
        self._running = run
        self._finished[rec.id] = asyncio.Event()
        await self.store.append_audit(actor=actor, source=source, action="job.start",
                                      params={"job_id": rec.id, "procedure": procedure, "options": opts})  # fmt: skip
        run.task = asyncio.create_task(self._run(run, cal, opts))
        return run

    async def cancel(self, job_id: int, *, actor: str, source: str, reason: str | None = None) -> JobRecord:
        """Stop the robot at once and end the job as cancelled (its partial dataset is kept)."""
        run = self._running
        if run is None or run.record.id != job_id:
            rec = await self.store.job(job_id)
            raise JobRefused(f"job {job_id} is not running (it is {rec.state}); nothing to cancel", conflict=True)
        await self._halt(run, actor=actor, source=source, reason=reason)
        if run.task is not None:
            with contextlib.suppress(asyncio.CancelledError):
                await asyncio.shield(run.task)
        return await self.store.job(job_id)

    async def _halt(self, run: RunningJob, *, actor: str, source: str, reason: str | None) -> None:
        """The first cancel of a job: audit it, stop the robot at once, cancel the job's task (a later one does nothing)."""
        if run.cancel_reason is not None:
            return
        job_id = run.record.id
        run.cancel_reason = reason or f"cancelled by {actor}"
        await self.store.append_audit(actor=actor, source=source, action="job.cancel", params={"job_id": job_id, "reason": run.cancel_reason})
        try:
            await self.devices.robot.stop(timeout_s=self.call_timeout_s)
        except DeviceError as err:
            log.error("job %d: the robot did not take the stop: %s", job_id, err)
        if run.task is not None:
            run.task.cancel()

    async def answer(self, job_id: int, prompt_id: int, answer: Answer) -> Prompt:
        """Answer the job's open prompt (audited with who answered)."""
        prompt = self.desk.answer(prompt_id, answer, job_id=job_id)
        await self.store.append_audit(
            actor=answer.actor, source=answer.source, action="job.prompt",
            params={"job_id": job_id, "prompt_id": prompt_id, "kind": prompt.kind.value, "action": answer.action, "value": answer.value},
        )  # fmt: skip
        return prompt

    # -- the job itself -------------------------------------------------------------------------

    def _publish(self, run: RunningJob) -> None:
        r = run.record
        prompts = self.desk.open_prompts(r.id)
        run.updates += 1
        self.events.publish(
            "job",
            {"job_id": r.id, "procedure": r.procedure, "state": r.state, "progress": run.progress, "frames": run.frames,
             "error": r.error, "dataset": r.dataset, "version_after": r.version_after, "plan": r.plan, "result": r.result,
             "finished_utc": None if r.finished_at is None else r.finished_at.isoformat(),
             "prompt": prompts[0].as_dict() if prompts else None, "update": run.updates},
        )  # fmt: skip

    def _progress(self, run: RunningJob) -> Callable[[int, int, str], None]:
        def report(done: int, total: int, message: str) -> None:
            if run.cancel_reason is not None:
                # The cancel's task.cancel() can be lost when it lands as an awaited driver call completes
                # (asyncio.wait_for on Python 3.11 may swallow it): the next step of the job ends it instead.
                raise asyncio.CancelledError(run.cancel_reason)
            run.note_progress(done, total, message)
            self._publish(run)
            if run.updates % PROGRESS_PERSIST_EVERY == 0 or done == total:
                asyncio.get_running_loop().create_task(self._persist_progress(run))

        return report

    async def _persist_progress(self, run: RunningJob) -> None:
        with contextlib.suppress(Exception):
            run.record = await self.store.update_job(run.record.id, progress=run.progress)

    def _on_plan(self, run: RunningJob) -> Callable[[MotionPlan], None]:
        def show(plan: MotionPlan) -> None:
            summary = plan.summary()
            run.record = replace(run.record, plan=summary)
            asyncio.get_running_loop().create_task(self._persist_plan(run, summary))
            self._publish(run)

        return show

    async def _persist_plan(self, run: RunningJob, summary: dict[str, Any]) -> None:
        with contextlib.suppress(Exception):
            await self.store.update_job(run.record.id, plan=summary)

    def _on_frame(self, run: RunningJob) -> Callable[[Frame], None]:
        def take(frame: Frame) -> None:
            run.frame = frame
            run.frames += 1
            self.events.publish("job_image", {"job_id": run.record.id, "frames": run.frames})

        return take

    async def _run(self, run: RunningJob, cal: CalibrationSet | None, opts: dict[str, Any]) -> None:
        rec = run.record
        proc = ALL_PROCEDURES[rec.procedure]
        config = config_for(self.config, opts)
        when = datetime.now(timezone.utc)
        dest = default_dataset_dir(self.calibration_store.root, proc.kind, when).with_name(
            f"{proc.kind}-{when:%Y%m%dT%H%M%S}Z-job{rec.id}"
        )
        motion = motion_settings(config)
        d = self.devices
        ctx = JobContext(
            job_id=rec.id, config=config,
            devices=replace(d, robot=ReducedSpeedRobot(d.robot, motion.speed_mm_s, motion.speed_deg_s)),
            calibration=cal, motion=motion, ask=self.desk.asker(rec.id), dest=dest, witness=self.witness,
            source=describe_source(config, d),
        )  # fmt: skip
        ctx.progress = self._progress(run)
        ctx.on_frame = self._on_frame(run)
        ctx.on_plan = self._on_plan(run)
        run.ctx = ctx
        fields: dict[str, Any] = {}
        outcome: Outcome | None = None
        ds: Dataset | None = None
        try:
            ds = await proc.collect(ctx, **{k: v for k, v in opts.items() if k in proc.options})
            fields["dataset"] = str(ds.root)
            run.record = await self.store.update_job(rec.id, state="computing", dataset=str(ds.root),
                                                     plan=None if ctx.plan is None else ctx.plan.summary())  # fmt: skip
            self._publish(run)
            outcome = await asyncio.to_thread(proc.compute, ds, cal, config)
            fields.update(await self._conclude(rec, proc, outcome, ds, config, opts, when))
        except (asyncio.CancelledError, Exception) as err:
            fields.update(ended_by(err, run.cancel_reason, rec.id))
        say_where_the_robot_was_left(fields, ctx.robot_left)
        # The record is written before the task ends: a cancel landing while it is written (the job saw
        # the cancel at its next step first) waits for it rather than answer with the job still running.
        _, cancelled = await to_the_end(self._finish(run, ctx, fields))
        if cancelled:
            raise asyncio.CancelledError

    async def _conclude(
        self, rec: JobRecord, proc: Procedure, outcome: Outcome, ds: Dataset, config: CellConfig, opts: Mapping[str, Any], when: datetime
    ) -> dict[str, Any]:
        result: dict[str, Any] = {"part": outcome.part, "method": outcome.method, "summary": list(outcome.summary),
                                  "warnings": list(outcome.warnings), "quality": outcome.quality}  # fmt: skip
        fields: dict[str, Any] = {"state": "done", "result": result}
        if not proc.records_part:
            if not outcome.quality.get("passed", False):
                await self.alarms.raise_alarm(AlarmCode.CALIBRATION_DRIFT, source="verify", detail="; ".join(outcome.warnings))
            elif self.schedule is not None:
                self.schedule.checked()
            return fields
        if opts.get("store", True):
            # Once the new version is being written it is written: a cancel landing now (the thread would commit
            # anyway) waits for it, and the job ends done with the version it stored, as the set in use then is.
            saved, late = await to_the_end(asyncio.to_thread(
                record, self.calibration_store, outcome, ds, config, when, f"{outcome.part}: job {rec.id}"))  # fmt: skip
            if late:
                result["cancel"] = "came while the new version was being written: it was stored and is in use"
            fields["version_after"] = saved.version
            result["stored_version"] = saved.version
            result["ready_problems"] = check_ready(
                saved, datetime.now(timezone.utc), recipe=opts.get("recipe"), first_recipe=self.config.default_recipe,
                config=self.config, store_root=self.calibration_store.root,
            )
        else:
            result["stored_version"] = None
        return fields

    async def _finish(self, run: RunningJob, ctx: JobContext, fields: dict[str, Any]) -> None:
        rec = run.record
        try:
            await keep_what_was_collected(ctx, fields, rec.id)
            if ctx.plan is not None:
                fields.setdefault("plan", ctx.plan.summary())
            fields["progress"] = run.progress or {}
            # The record says the job ended and the manager takes the next one at the same moment:
            # a client that sees "done" and submits again is not refused as "one job at a time".
            async with self._lock:
                run.record = await self.store.update_job(rec.id, **fields)
                self._running = None
            run.ctx = None  # the dataset's frames go with it
            await asyncio.to_thread(release_free_memory)
            if run.frame is not None:
                self._last_frames[rec.id] = run.frame
                while len(self._last_frames) > LAST_FRAMES_KEPT:
                    self._last_frames.pop(next(iter(self._last_frames)))
            self._publish(run)
            log.info("commissioning job %d (%s) ended %s%s", rec.id, rec.procedure, run.record.state,
                     f": {run.record.error}" if run.record.error else "")  # fmt: skip
        finally:
            if self._running is run:  # the store update failed: free the manager anyway
                self._running = None
            ev = self._finished.pop(rec.id, None)
            if ev is not None:
                ev.set()
