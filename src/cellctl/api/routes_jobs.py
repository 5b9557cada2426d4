"""Commissioning routes: start, follow, answer and cancel calibration, teaching and verification jobs.

``POST /jobs`` starts a job (``POST /jobs/plan`` only plans it); the job then shows its prompts,
progress and live image on ``GET /jobs/{id}`` and on the event stream (``job``, ``job_image`` and
``prompt`` events). ``cellctl calibrate ...`` and the dashboard's commissioning page use these.
"""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, Depends, HTTPException, Query, Response, status

from cellctl.api.auth import Caller, TokenGuard
from cellctl.api.dashboard import scaled_png
from cellctl.api.schemas import JobId, PromptId
from cellctl.api.schemas_jobs import (
    JobRequestBody,
    JobView,
    PlanView,
    ProcedureView,
    PromptAnswerBody,
    PromptView,
)
from cellctl.calibration.calibration_set import COMMANDS
from cellctl.commissioning.jobs import JobManager
from cellctl.commissioning.plans import laser_poses_floor
from cellctl.commissioning.prompts import Answer, PromptError, UnknownPrompt
from cellctl.commissioning.registry import (
    ALL_PROCEDURES,
    HAND_EYE_METHODS,
    JobRefused,
    check_options,
    job_view,
)
from cellctl.store import UnknownJob

IMAGE_WIDTH_MAX = 2048


def build_router(jobs: JobManager, guard: TokenGuard) -> APIRouter:
    """Starting, cancelling and answering jobs needs an engineer's token (``auth.ROUTE_ROLES``); ``reads`` (planning too) need read access."""
    router = APIRouter(tags=["commissioning"])
    reads = APIRouter(tags=["commissioning"], dependencies=guard.reads())

    async def view(job_id: int) -> JobView:
        try:
            rec = await jobs.job(job_id)
        except UnknownJob:
            raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no job {job_id}") from None
        return JobView.model_validate(job_view(rec, jobs.live(job_id)))

    def refused(err: JobRefused) -> HTTPException:
        return HTTPException(status.HTTP_409_CONFLICT if err.conflict else 422, detail=str(err))

    @reads.get("/procedures", response_model=list[ProcedureView])
    async def procedures() -> list[ProcedureView]:
        c = jobs.config.calibration.procedure
        defaults = {"views": c.camera.n_views, "poses": c.laser.n_poses, "store": True, "method": c.hand_eye.method,
                    "recipe": jobs.config.default_recipe}  # fmt: skip
        recipes = list(jobs.config.process.recipe_names().values())
        limits = {"views": [3.0, 200.0], "poses": [float(laser_poses_floor(jobs.config)), 5000.0]}
        out = []
        for name, p in ALL_PROCEDURES.items():
            options = p.option_names()
            out.append(ProcedureView(
                name=name, part=p.part, dataset_kind=p.kind, needs=list(p.needs), options=options,
                command=COMMANDS.get(name, "cellctl calibrate verify"),
                defaults={k: defaults[k] for k in options}, limits={k: limits[k] for k in options if k in limits},
                choices={"method": list(HAND_EYE_METHODS)} if name == "hand_eye" else {"recipe": recipes} if "recipe" in options else {},
            ))  # fmt: skip
        return out

    @reads.get("/jobs", response_model=list[JobView])
    async def list_jobs(limit: int = Query(20, ge=1, le=500)) -> list[JobView]:
        return [JobView.model_validate(job_view(r, jobs.live(r.id))) for r in await jobs.store.jobs(limit=limit)]

    planning: set[str] = set()  # the plan being worked out (one at a time)

    @reads.post("/jobs/plan", response_model=PlanView,
                responses={409: {"description": "a device the procedure uses is lost (the watchdog's alarm is active)"},
                           422: {"description": "no plan: the reason names the setting"},
                           429: {"description": "another plan is being worked out: retry when it is answered"}})  # fmt: skip
    async def plan_job(body: JobRequestBody, poses: bool = Query(False, description="list every pose")) -> PlanView:
        # Open to readers: one plan at a time, all of it off the event loop (thousands of poses take seconds).
        options = body.options.model_dump(exclude_none=True)
        try:
            check_options(body.procedure, options, jobs.config)  # a bad option is a 422 even while another plan runs
        except JobRefused as err:
            raise refused(err) from None
        if planning:
            raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, headers={"Retry-After": "1"}, detail=(
                f"POST /jobs/plan: a plan of {next(iter(planning))} is being worked out; plans are worked out one at "
                "a time (each takes the CPU a cycle needs): retry when it is answered"))  # fmt: skip

        async def work() -> PlanView:
            plan = await jobs.plan(body.procedure, options)
            return await asyncio.to_thread(lambda: PlanView.model_validate(plan.summary(with_poses=poses)))

        def done(t: asyncio.Future[PlanView]) -> None:  # when the work ends, even if the caller left before
            planning.clear()
            if not t.cancelled():
                t.exception()  # retrieved: a refusal nobody waits for any more is not logged as lost

        planning.add(body.procedure)
        task = asyncio.ensure_future(work())
        task.add_done_callback(done)
        try:
            return await asyncio.shield(task)
        except JobRefused as err:
            raise refused(err) from None

    @router.post("/jobs", response_model=JobView, status_code=status.HTTP_201_CREATED,
                 responses={409: {"description": "another job runs, the cell is not in Stopped or Idle, or a device the procedure uses is lost"}, 422: {"description": "bad options"}})  # fmt: skip
    async def start_job(body: JobRequestBody, caller: Caller = Depends(guard.require)) -> JobView:
        try:
            rec = await jobs.submit(body.procedure, body.options.model_dump(exclude_none=True), actor=caller.actor, source=f"rest:{caller.source}")
        except JobRefused as err:
            raise refused(err) from None
        return await view(rec.id)

    @reads.get("/jobs/{job_id}", response_model=JobView, responses={404: {"description": "no such job"}})
    async def get_job(job_id: JobId) -> JobView:
        return await view(job_id)

    @router.post("/jobs/{job_id}/cancel", response_model=JobView, responses={409: {"description": "the job is not running"}})
    async def cancel_job(job_id: JobId, caller: Caller = Depends(guard.require)) -> JobView:
        try:
            await jobs.cancel(job_id, actor=caller.actor, source=f"rest:{caller.source}")
        except JobRefused as err:
            raise refused(err) from None
        except UnknownJob:
            raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no job {job_id}") from None
        return await view(job_id)

    @router.post("/jobs/{job_id}/prompts/{prompt_id}", response_model=PromptView,
                 responses={404: {"description": "no such open prompt"}, 422: {"description": "an answer the prompt cannot take"}})  # fmt: skip
    async def answer_prompt(
        job_id: JobId, prompt_id: PromptId, body: PromptAnswerBody, caller: Caller = Depends(guard.require)
    ) -> PromptView:
        if body.action not in ("confirm", "cancel", "value"):
            raise HTTPException(422, detail=f"action: 'confirm', 'cancel' or 'value', got '{body.action}'")
        try:
            prompt = await jobs.answer(job_id, prompt_id, Answer(body.action, body.value, caller.actor, f"rest:{caller.source}"))  # type: ignore[arg-type]
        except UnknownPrompt as err:
            raise HTTPException(status.HTTP_404_NOT_FOUND, detail=str(err)) from None
        except PromptError as err:
            raise HTTPException(422, detail=str(err)) from None
        return PromptView.model_validate(prompt.as_dict())

    @reads.get("/jobs/{job_id}/image", response_class=Response,
               responses={200: {"content": {"image/png": {}}, "description": "the job's last frame, scaled"}, 404: {"description": "no frame yet"}})  # fmt: skip
    async def job_image(
        job_id: JobId,
        width: int = Query(640, ge=16, le=IMAGE_WIDTH_MAX),
        frame_count: int | None = Query(None, alias="frame", ge=0, description="not used: gives each new frame its own URL"),
    ) -> Response:
        frame = jobs.latest_frame(job_id)
        if frame is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"job {job_id} has no frame (yet)")
        png = await asyncio.to_thread(scaled_png, frame.image, width)
        return Response(png, media_type="image/png", headers={"Cache-Control": "no-store"})

    router.include_router(reads)
    return router
