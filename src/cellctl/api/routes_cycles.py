"""Cycle routes: POST /cycle (idempotent), the cycle records and their images."""

from __future__ import annotations

from dataclasses import asdict
from datetime import datetime
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Depends, Header, HTTPException, Query, Response, status
from fastapi.responses import FileResponse

from cellctl.api.auth import Caller, TokenGuard
from cellctl.api.schemas import BeforeId, CycleId, ErrorBody
from cellctl.api.schemas_cycles import (
    CycleAccepted,
    CycleBrief,
    CycleRequestBody,
    CycleView,
    ImageView,
    StepView,
)
from cellctl.cell.orchestrator import CellOrchestrator, CycleRefused
from cellctl.cell.outcome import measured_of
from cellctl.store import (
    CycleRecord,
    CycleRequest,
    CycleState,
    IdempotencyConflict,
    UnknownCycle,
)
from cellctl.store.records import MAX_TEXT_LEN


def cycle_brief(record: CycleRecord) -> CycleBrief:
    """A cycle record as ``GET /cycles`` lists it (without steps and images)."""
    return CycleBrief(**_brief_fields(record))


def cycle_view(record: CycleRecord) -> CycleView:
    """A cycle record as the API shows it, with its steps and images."""
    steps = [
        StepView(
            step=s.step.name.lower(), attempt=s.attempt, started_at=s.started_at.isoformat(), duration_s=s.duration_s,
            ok=s.ok, figures=dict(s.figures), error=s.error,
        )
        for s in record.steps
    ]  # fmt: skip
    images = [
        ImageView(
            name=i.name, step=i.step.name.lower(), url=f"/cycles/{record.id}/images/{i.name}",
            pruned_at=i.pruned_at.isoformat() if i.pruned_at else None, pruned_reason=i.pruned_reason,
        )
        for i in record.images
    ]  # fmt: skip
    return CycleView(**_brief_fields(record), steps=steps, images=images)


def _measured(record: CycleRecord) -> dict[str, float] | None:
    m = measured_of(dict(record.result or {}))
    return None if m is None else asdict(m)


def _brief_fields(record: CycleRecord) -> dict[str, Any]:
    def iso(t: datetime | None) -> str | None:
        return t.isoformat() if t else None

    return {
        "id": record.id,
        "state": record.state.value,
        "recipe": record.request.recipe,
        "part_id": record.request.part_id,
        "car_id": record.request.car_id,
        "source": record.request.source,
        "actor": record.actor,
        "idempotency_key": record.idempotency_key,
        "current_step": record.current_step.name.lower(),
        "result": None if record.result is None else dict(record.result),
        "error": record.error,
        "true_error": None if record.true_error is None else dict(record.true_error),
        "measured_deviation": _measured(record),
        "part_ok": None if record.result is None else record.result.get("part_ok"),
        "created_at": record.created_at.isoformat(),
        "started_at": iso(record.started_at),
        "finished_at": iso(record.finished_at),
        "install_started_at": iso(record.install_started_at),
        "interrupted_step": record.interrupted_step.name.lower() if record.interrupted_step else None,
    }


async def image_file(orch: CellOrchestrator, cycle_id: int, name: str) -> Path:
    """The file of a cycle's image, or the HTTP error that says why there is none."""
    try:
        record = await orch.store.cycle(cycle_id)
    except UnknownCycle:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no cycle {cycle_id}") from None
    ref = next((i for i in record.images if i.name == name), None)
    if ref is None or len(name) > MAX_TEXT_LEN:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"cycle {cycle_id} has no image '{name}'")
    if ref.pruned:
        when = ref.pruned_at.isoformat() if ref.pruned_at else "earlier"
        raise HTTPException(status.HTTP_410_GONE, detail=f"image {name} of cycle {cycle_id} was pruned {when}: {ref.pruned_reason}")
    path = orch.image_dir / ref.uri
    if not path.is_file():
        raise HTTPException(status.HTTP_410_GONE, detail=f"image file {ref.uri} is no longer on disk")
    return path


def build_router(orch: CellOrchestrator, guard: TokenGuard, wait_max_s: float) -> APIRouter:
    """``POST /cycle`` (an operator's token, ``auth.ROUTE_ROLES``) and the cycle records (``reads``: read access)."""
    router = APIRouter(tags=["cycles"])
    reads = APIRouter(tags=["cycles"], dependencies=guard.reads())

    @router.post(
        "/cycle",
        status_code=status.HTTP_202_ACCEPTED,
        response_model=None,
        responses={
            200: {"model": CycleView, "description": "with ?wait=true: the finished cycle"},
            202: {"model": CycleAccepted, "description": "queued (or already known under this key)"},
            401: {"model": ErrorBody, "description": "no or wrong bearer token"},
            409: {"model": ErrorBody, "description": "the cell is not in a state to take a cycle"},
            422: {"model": ErrorBody, "description": "bad body or header, or the key was used for a different request"},
        },
    )
    async def post_cycle(
        body: CycleRequestBody,
        response: Response,
        idempotency_key: str = Header(
            ..., alias="Idempotency-Key", min_length=1, max_length=128, description="one key per intended cycle"
        ),
        wait: bool = Query(False, description="answer when the cycle has finished (or after timeout_s)"),
        timeout_s: float = Query(120.0, gt=0, description="how long ?wait=true waits"),
        caller: Caller = Depends(guard.require),
    ) -> CycleAccepted | CycleView:
        if not idempotency_key.strip():  # the store's rule (a key of white space only, e.g. U+00A0, is no key)
            raise HTTPException(422, detail="header field 'Idempotency-Key': blank; send one non-blank key per intended cycle (e.g. a UUID)")
        known = sorted(orch.config.process.recipe_names().values())
        if body.recipe not in known:
            raise HTTPException(
                422,
                detail=f"body field 'recipe': unknown recipe '{body.recipe}'; known recipes: {known}",
            )
        try:
            request = CycleRequest(body.recipe, body.part_id, body.car_id, source=f"rest:{caller.source}")
        except ValueError as err:  # the store's own check (the body's patterns are the same rule): names the field
            raise HTTPException(422, detail=f"body: {err}") from None
        try:
            sub = await orch.submit_cycle(
                request,
                scope="rest",
                key=idempotency_key,
                actor=caller.actor,
            )
        except CycleRefused as err:
            raise HTTPException(status.HTTP_409_CONFLICT, detail=err.reason) from None
        except IdempotencyConflict as err:
            raise HTTPException(422, detail=str(err)) from None
        cid, state = sub.cycle.id, sub.cycle.state
        if wait:
            record = await orch.wait_cycle(cid, min(timeout_s, wait_max_s))
            if record.state in (CycleState.DONE, CycleState.FAILED, CycleState.INTERRUPTED):
                response.status_code = status.HTTP_200_OK
                return cycle_view(record)
            state = record.state  # the wait timed out: the state the cycle is in now, not when it was queued
        return CycleAccepted(
            cycle_id=cid,
            state=state.value,
            created=sub.created,
            links={"self": f"/cycles/{cid}", "events": "/events"},
        )

    @reads.get("/cycles", response_model=list[CycleBrief])
    async def list_cycles(
        limit: int = Query(50, ge=1, le=1000),
        before_id: BeforeId = None,
        state: CycleState | None = None,
    ) -> list[CycleBrief]:
        records = await orch.store.cycles(limit=limit, before_id=before_id, state=state)
        return [cycle_brief(r) for r in records]

    @reads.get("/cycles/{cycle_id}", response_model=CycleView, responses={404: {"model": ErrorBody, "description": "no such cycle"}})
    async def get_cycle(cycle_id: CycleId) -> CycleView:
        try:
            return cycle_view(await orch.store.cycle(cycle_id))
        except UnknownCycle:
            raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no cycle {cycle_id}") from None

    @reads.get(
        "/cycles/{cycle_id}/images/{name}",
        response_class=FileResponse,
        responses={
            200: {"content": {"image/png": {}}, "description": "the PNG image"},
            404: {"model": ErrorBody, "description": "no such cycle, or no image of that name"},
            410: {"model": ErrorBody, "description": "the image file is no longer on disk"},
        },
    )
    async def get_image(cycle_id: CycleId, name: str) -> FileResponse:
        return FileResponse(await image_file(orch, cycle_id, name), media_type="image/png")

    router.include_router(reads)
    return router
