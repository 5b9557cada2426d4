"""The closed loop over measured install results: ``GET /spc`` and ``POST /spc/reset``."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, Query

from cellctl.api.auth import Caller, TokenGuard
from cellctl.api.schemas_quality import SpcHistoryEntry, SpcPage, SpcView
from cellctl.cell.orchestrator import CellOrchestrator
from cellctl.store import ALL_RECIPES

RECIPE = Query(None, description="a recipe's name (each recipe has its own loop); none: every recipe")


def build_router(orch: CellOrchestrator, guard: TokenGuard) -> APIRouter:
    """``/spc`` needs read access, its reset an engineer's token (``auth.ROUTE_ROLES``)."""
    router = APIRouter(tags=["quality"])
    reads = APIRouter(tags=["quality"], dependencies=guard.reads())

    def known(recipe: str | None) -> str | None:
        if recipe is not None and recipe not in orch.quality.recipes:
            raise HTTPException(422, detail=f"query field 'recipe': unknown recipe {recipe!r}; known recipes: {orch.quality.recipes}")
        return recipe

    @reads.get("/spc", response_model=SpcPage)
    async def get_spc(limit: int = Query(100, ge=1, le=1000), recipe: str | None = RECIPE) -> SpcPage:
        loops = orch.quality
        rows = await orch.store.spc_history(limit=limit, recipe=ALL_RECIPES if known(recipe) is None else recipe)
        history = [
            SpcHistoryEntry(
                id=r.id, recorded_at=r.recorded_at.isoformat(), recipe=r.recipe or loops.first_recipe, cycle_id=r.cycle_id,
                calibration_version=r.calibration_version, events=list(r.events), excluded=r.excluded,
                u=None if r.u is None else dict(r.u), estimate=dict(r.estimate), offset=dict(r.offset), drifting=list(r.drifting),
            )  # fmt: skip
            for r in rows
        ]
        now = SpcView.model_validate(loops.view(recipe or loops.first_recipe))
        return SpcPage(now=now, recipes=[SpcView.model_validate(loops.view(n)) for n in loops.recipes], history=history)

    @router.post("/spc/reset", response_model=SpcView)
    async def reset_spc(caller: Caller = Depends(guard.require), recipe: str | None = RECIPE) -> SpcView:
        """Forget the estimate and any drift of a recipe's loop, or of every recipe's (after a repair that needs no
        recalibration; a new calibration set resets by itself). Answers the (first) recipe's loop."""
        await orch.quality.reset(actor=caller.actor, source=f"rest:{caller.source}", recipe=known(recipe))
        return SpcView.model_validate(orch.quality.view(recipe or orch.quality.first_recipe))

    router.include_router(reads)
    return router
