"""Cell routes: status, PackML commands and unit mode, alarms, calibration, events, health, metrics."""

from __future__ import annotations

import asyncio
import enum
import json
import time
from collections.abc import AsyncIterator
from datetime import datetime, timezone

from fastapi import APIRouter, Depends, HTTPException, Request, Response, status
from fastapi.responses import StreamingResponse
from pydantic import Field

from cellctl.api.auth import SECURITY_SCHEME, Caller, TokenGuard
from cellctl.api.health import judge
from cellctl.api.metrics import CONTENT_TYPE_LATEST, CellMetrics
from cellctl.api.schemas_cell import (
    AlarmsView,
    AlarmView,
    CalibrationView,
    CommandResult,
    HealthView,
    LiveView,
    StatusView,
    StoreHealth,
)
from cellctl.cell.alarms import UnknownAlarm
from cellctl.cell.orchestrator import CellOrchestrator
from cellctl.cell.packml import CommandRefused, ModeChangeNotAllowed, TakenCommand
from cellctl.domain import Alarm, PackMLCommand, UnitMode

CommandName = enum.Enum("CommandName", {c.name.lower(): c.name.lower() for c in PackMLCommand if c.value})  # type: ignore[misc]
ModeName = enum.Enum("ModeName", {m.name.lower(): m.name.lower() for m in UnitMode if m.value})  # type: ignore[misc]

SSE_STATUS_PERIOD_S = 2.0
"""/events sends a fresh ``status`` event at least this often: device heartbeat ages stay current on
the dashboard, and a client that hears nothing for a few periods knows its data is stale (an SSE
comment would not do: EventSource never shows comments to the page)."""


class CommandAnswer(CommandResult):
    """A PackML command the cell carried out: by the state table, or where it has no edge by the cell's own rule."""

    effect: str | None = Field(
        None, description="what the command did where the state table has no edge for it, the state staying "
        "(e.g. a Stop in Stopped cancels the running commissioning job); absent for a table edge",
    )  # fmt: skip


def alarm_view(a: Alarm) -> AlarmView:
    """An alarm as the API shows it."""
    return AlarmView(
        uid=a.uid,
        code=int(a.code),
        value=a.value,
        message=a.message,
        category=a.category.name.lower(),
        severity=a.severity.name.lower(),
        source=a.source,
        raised_at=a.raised_at.isoformat(),
        active=a.active,
        acknowledged=a.acknowledged,
        ack_by=a.ack_by,
        ack_at=a.ack_at.isoformat() if a.ack_at else None,
        cleared_at=a.cleared_at.isoformat() if a.cleared_at else None,
        reaction=a.reaction.name.lower() if a.reaction else None,
        cycle_id=a.cycle_id,
    )


def build_router(orch: CellOrchestrator, guard: TokenGuard) -> APIRouter:
    """The cell routes: mutating ones a token of the role ``auth.ROUTE_ROLES`` names, ``reads`` read access; ``/health`` is open."""
    router = APIRouter(tags=["cell"])
    reads = APIRouter(tags=["cell"], dependencies=guard.reads())
    cell_metrics = CellMetrics(orch)

    @reads.get("/status", response_model=StatusView, response_model_exclude_unset=True)
    async def get_status() -> StatusView:
        return StatusView.model_validate(orch.status())

    @router.post(
        "/commands/{name}", response_model=CommandAnswer, response_model_exclude_none=True,
        responses={409: {"description": "the state table forbids it now (and no job is there for a Stop in Stopped to cancel)"}},
    )  # fmt: skip
    async def post_command(name: CommandName, caller: Caller = Depends(guard.require)) -> CommandAnswer:  # type: ignore[valid-type]
        cmd = PackMLCommand[name.value.upper()]  # type: ignore[attr-defined]
        try:
            ev = await orch.command(cmd, actor=caller.actor, source=f"rest:{caller.source}")
        except CommandRefused as err:
            raise HTTPException(status.HTTP_409_CONFLICT, detail=str(err)) from None
        effect = ev.effect if isinstance(ev, TakenCommand) else None
        return CommandAnswer(command=cmd.name.lower(), state=ev.state_after.name, mode=ev.mode_after.name, effect=effect)

    @router.post("/mode/{name}", response_model=CommandResult, responses={409: {"description": "modes change only in some states"}})
    async def post_mode(name: ModeName, caller: Caller = Depends(guard.require)) -> CommandResult:  # type: ignore[valid-type]
        mode = UnitMode[name.value.upper()]  # type: ignore[attr-defined]
        try:
            ev = await orch.machine.change_mode(mode, actor=caller.actor, source=f"rest:{caller.source}")
        except ModeChangeNotAllowed as err:
            raise HTTPException(status.HTTP_409_CONFLICT, detail=str(err)) from None
        return CommandResult(command=f"mode:{mode.name.lower()}", state=ev.state_after.name, mode=ev.mode_after.name)

    @reads.get("/alarms", response_model=AlarmsView, response_model_exclude_unset=True)
    async def get_alarms(history: bool = False) -> AlarmsView:
        stop = orch.alarms.stop_reason
        view = AlarmsView(current=[alarm_view(a) for a in orch.alarms.current()], stop_reason=None if stop is None else alarm_view(stop))
        if history:
            view.history = [alarm_view(a) for a in await orch.store.alarms(limit=200)]
        return view

    @router.post("/alarms/{uid}/acknowledge", response_model=AlarmView)
    async def acknowledge(uid: str, caller: Caller = Depends(guard.require)) -> AlarmView:
        try:
            alarm = orch.alarms.acknowledge(uid, by=caller.actor)
        except UnknownAlarm:
            raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no current alarm with uid '{uid}'") from None
        await orch.records.writes.audit(  # it took effect: its entry is kept while the store refuses it, never a 500
            actor=caller.actor, source=f"rest:{caller.source}", action="alarm.acknowledge",
            params={"uid": uid, "code": int(alarm.code)},
        )  # fmt: skip
        return alarm_view(alarm)

    @router.post("/alarms/acknowledge-all", response_model=list[AlarmView])
    async def acknowledge_all(caller: Caller = Depends(guard.require)) -> list[AlarmView]:
        done = orch.alarms.acknowledge_all(by=caller.actor)
        await orch.records.writes.audit(  # as for one alarm: kept while the store refuses it
            actor=caller.actor, source=f"rest:{caller.source}", action="alarm.acknowledge_all",
            params={"uids": [a.uid for a in done]},
        )  # fmt: skip
        return [alarm_view(a) for a in done]

    @reads.get("/calibration", response_model=CalibrationView, response_model_exclude_unset=True)
    async def get_calibration() -> CalibrationView:
        versions = await asyncio.to_thread(orch.calibration.history)
        now = datetime.now(timezone.utc)  # every verdict below is reckoned at this one instant
        return CalibrationView.model_validate({"current": orch.calibration.summary(now=now), "problems": orch.calibration.problems(now=now),
                                               "versions": versions, "now_utc": now.isoformat()})  # fmt: skip

    @reads.get(
        "/events", response_class=StreamingResponse,
        responses={200: {"content": {"text/event-stream": {}}, "description": "server-sent events: `status` (the /status document, StatusView), state (with its allowed and blocked commands while it lasts), alarm, cycle, step, image, job, prompt, ..."}},
    )  # fmt: skip
    async def events(request: Request) -> StreamingResponse:
        queue = orch.events.subscribe()

        def status_event() -> str:  # the /status document, through the same model
            return f"event: status\ndata: {StatusView.model_validate(orch.status()).model_dump_json(exclude_unset=True)}\n\n"

        async def stream() -> AsyncIterator[str]:
            try:
                yield status_event()
                last_status = time.monotonic()
                while not orch.events.closing and not await request.is_disconnected():
                    wait_s = last_status + SSE_STATUS_PERIOD_S - time.monotonic()
                    if wait_s <= 0:
                        yield status_event()
                        last_status = time.monotonic()
                        continue
                    try:
                        ev = await asyncio.wait_for(queue.get(), wait_s)
                    except TimeoutError:
                        continue
                    yield f"id: {ev.seq}\nevent: {ev.kind}\ndata: {json.dumps(ev.data)}\n\n"
                    if ev.kind == "shutdown":  # the service is stopping: end the stream so shutdown need not wait for it
                        return
            finally:
                orch.events.unsubscribe(queue)

        return StreamingResponse(stream(), media_type="text/event-stream", headers={"Cache-Control": "no-store"})

    @router.get(
        "/health",
        response_model=HealthView,
        response_model_exclude_none=True,
        responses={503: {"model": HealthView, "description": "not healthy: `problems` says why (with the details)"}},
        openapi_extra={"security": [{}, {SECURITY_SCHEME: []}]},  # open; with closed reads a token shows the details
    )
    async def health(request: Request, response: Response) -> HealthView:
        """Readiness: 200 when the cell can work, 503 when a device link or the PLC link is down, the store
        does not answer (within a second) or refuses writes (alarm 1703), or the service is stopping (the rules:
        ``cellctl.api.health``).

        With ``[api] open_reads = false`` an anonymous caller (a plant's up/down monitor) gets ``ok``
        alone (and the status code); the details need the token. The database's path is never shown.
        """
        verdict = await judge(orch)
        if not verdict.ok:
            response.status_code = status.HTTP_503_SERVICE_UNAVAILABLE
        if not guard.may_read_details(request):
            return HealthView(ok=verdict.ok)
        store = None if verdict.journal_mode is None else StoreHealth(journal_mode=verdict.journal_mode)
        return HealthView(ok=verdict.ok, devices_lost=verdict.devices_lost, plc=verdict.plc, problems=verdict.problems, store=store)

    @router.get("/health/live", response_model=LiveView)
    async def health_live() -> LiveView:
        """Liveness: 200 while the process serves HTTP, whatever the cell's state (restart it only when this fails)."""
        return LiveView()

    @reads.get(
        "/metrics",
        response_class=Response,  # errors stay JSON (ErrorBody); the metrics are text
        responses={200: {"content": {"text/plain": {"schema": {"type": "string"}}}, "description": "the cell's figures"}},
    )
    async def metrics() -> Response:
        """Prometheus text format. With ``[api] open_reads = false`` the scraper sends the token (its ``authorization``)."""
        return Response(await cell_metrics.exposition(), media_type=CONTENT_TYPE_LATEST)

    router.include_router(reads)
    return router
