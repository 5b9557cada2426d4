"""The closed loop over measured install results: ``GET /spc`` and ``POST /spc/reset``."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query

from cellctl.api.auth import Caller, TokenGuard
from cellctl.api.schemas_quality import SpcHistoryEntry, SpcPage, SpcView
from cellctl.cell.orchestrator import CellOrchestrator


def build_router(orch: CellOrchestrator, guard: TokenGuard) -> APIRouter:
    """``/spc`` needs read access, its reset the operator's token."""
    router = APIRouter(tags=["quality"])
    reads = APIRouter(tags=["quality"], dependencies=guard.reads())

    @reads.get("/spc", response_model=SpcPage)
    async def get_spc(limit: int = Query(100, ge=1, le=1000)) -> SpcPage:
        rows = await orch.store.spc_history(limit=limit)
        history = [
            SpcHistoryEntry(
                id=r.id, recorded_at=r.recorded_at.isoformat(), cycle_id=r.cycle_id, calibration_version=r.calibration_version,
                events=list(r.events), excluded=r.excluded, u=None if r.u is None else dict(r.u), estimate=dict(r.estimate),
                offset=dict(r.offset), drifting=list(r.drifting),
            )  # fmt: skip
            for r in rows
        ]
        return SpcPage(now=SpcView.model_validate(orch.quality.snapshot()), history=history)

    @router.post("/spc/reset", response_model=SpcView)
    async def reset_spc(caller: Caller = Depends(guard.require)) -> SpcView:
        """Forget the estimate and any drift (after a repair that needs no recalibration; a new calibration set resets by itself)."""
        await orch.quality.reset(actor=caller.actor, source=f"rest:{caller.source}")
        return SpcView.model_validate(orch.quality.snapshot())

    router.include_router(reads)
    return router
