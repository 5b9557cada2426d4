"""The FastAPI application: routes, locally served OpenAPI docs, and errors that name the field."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from swagger_ui_bundle import swagger_ui_path

import cellctl
from cellctl.api import dashboard, routes_cell, routes_cycles, routes_jobs
from cellctl.api.auth import TokenGuard
from cellctl.cell.orchestrator import CellOrchestrator
from cellctl.commissioning.jobs import JobManager
from cellctl.config.api import ApiConfig


def _field_errors(exc: RequestValidationError) -> list[dict[str, Any]]:
    out = []
    for e in exc.errors():
        loc = [str(p) for p in e.get("loc", ())]
        where = loc[0] if loc else "request"
        field = ".".join(loc[1:]) or where
        out.append({"in": where, "field": field, "message": e.get("msg", "invalid"), "type": e.get("type")})
    return out


def create_app(orch: CellOrchestrator, config: ApiConfig, jobs: JobManager | None = None) -> FastAPI:
    """The cell's HTTP face. The orchestrator (and the job manager) must be started by whoever runs the app."""
    app = FastAPI(
        title="cellctl",
        version=cellctl.__version__,
        description="Cell controller for robotic installation of large planar workpieces.",
        docs_url=None,
        redoc_url=None,
    )
    guard = TokenGuard(config)
    app.state.orchestrator = orch

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = _field_errors(exc)
        summary = "; ".join(f"{e['in']} field '{e['field']}': {e['message']}" for e in errors)
        return JSONResponse(status_code=422, content={"detail": summary, "errors": errors})

    app.include_router(routes_cycles.build_router(orch, guard, config.cycle_wait_max_s))
    app.include_router(routes_cell.build_router(orch, guard))
    if jobs is not None:
        app.include_router(routes_jobs.build_router(jobs, guard))
    dashboard.install(app, orch, guard)

    app.mount("/static/swagger-ui", StaticFiles(directory=str(swagger_ui_path)), name="swagger-ui")

    @app.get("/docs", include_in_schema=False)
    async def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url="/openapi.json",
            title="cellctl API",
            swagger_js_url="/static/swagger-ui/swagger-ui-bundle.js",
            swagger_css_url="/static/swagger-ui/swagger-ui.css",
            swagger_favicon_url="/static/swagger-ui/favicon-32x32.png",
        )

    return app
