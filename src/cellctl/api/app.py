"""The FastAPI application: routes, locally served OpenAPI docs, and errors that name the field."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from fastapi import APIRouter, Depends, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles
from starlette.routing import BaseRoute
from swagger_ui_bundle import swagger_ui_path

import cellctl
from cellctl.api import (
    dashboard,
    routes_cell,
    routes_cycles,
    routes_jobs,
    routes_parts,
    routes_quality,
)
from cellctl.api.auth import ROUTE_ROLES, SECURITY_SCHEMES, TokenBeforeBody, TokenGuard
from cellctl.api.limits import BodySizeLimit
from cellctl.api.query_params import refuse_unknown_query
from cellctl.api.schemas import ErrorBody
from cellctl.cell.orchestrator import CellOrchestrator
from cellctl.commissioning.jobs import JobManager
from cellctl.config.api import ApiConfig

ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorBody, "description": "the request body cannot be read as JSON text (e.g. it is not UTF-8)"},
    401: {"model": ErrorBody, "description": "no or wrong bearer token (mutating routes; every route with open_reads = false)"},
    413: {"model": ErrorBody, "description": "the request body is larger than [api] max_body_bytes"},
    422: {"model": ErrorBody, "description": "a bad request: `detail` names each bad field, `errors` lists them"},
}
"""The errors any route may answer, all in the app's one error body (it replaces FastAPI's default 422 schema)."""

ERROR_BODY_REF = {"$ref": "#/components/schemas/ErrorBody"}


def _field_errors(exc: RequestValidationError) -> list[dict[str, Any]]:
    out = []
    for e in exc.errors():
        loc = [str(p) for p in e.get("loc", ())]
        where = loc[0] if loc else "request"
        if e.get("type") == "json_invalid":  # its loc is ('body', <character offset>), not a field
            out.append({"in": where, "field": where, "message": _json_invalid_message(e), "type": "json_invalid"})
            continue
        field = ".".join(loc[1:]) or where
        out.append({"in": where, "field": field, "message": e.get("msg", "invalid"), "type": e.get("type")})
    return out


def _json_invalid_message(error: dict[str, Any]) -> str:
    """Where and why a body is not JSON: pydantic puts the character offset in ``loc`` and the reason in ``ctx``."""
    loc = error.get("loc", ())
    at = f" at character {loc[1]}" if len(loc) > 1 else ""
    reason = (error.get("ctx") or {}).get("error")
    return f"not valid JSON{at}" + (f" ({reason})" if reason else "") + "; send a JSON object"


def _summary(errors: list[dict[str, Any]]) -> str:
    """The 422's ``detail``: each error as "<in> field '<name>': <message>" (or "<in>: <message>" for the whole body)."""
    return "; ".join(
        f"{e['in']}: {e['message']}" if e["field"] == e["in"] else f"{e['in']} field '{e['field']}': {e['message']}"
        for e in errors
    )


def document_error_bodies(schema: dict[str, Any]) -> dict[str, Any]:
    """Every error answer in the OpenAPI document as it is sent: an ``ErrorBody``.

    A route that names an error with a description alone (``409: {"description": ...}``) gets the
    body added; a route with path parameters may answer 404 (what the path names does not exist).
    """
    for ops in schema.get("paths", {}).values():
        for op in ops.values():
            responses = op.get("responses", {})
            if any(p.get("in") == "path" for p in op.get("parameters", [])):
                responses.setdefault("404", {"description": "nothing of that name or id"})
            for code, response in responses.items():
                if code.startswith("4") and not response.get("content"):
                    response["content"] = {"application/json": {"schema": ERROR_BODY_REF}}
    return schema


def api_routes_of(routes: list[BaseRoute]) -> Iterator[APIRoute]:
    """Every APIRoute in ``routes``, also inside included routers (FastAPI may keep those as one route each)."""
    for route in routes:
        if isinstance(route, APIRoute):
            yield route
        inner = getattr(route, "original_router", None)
        if inner is not None:
            yield from api_routes_of(inner.routes)


def document_security(schema: dict[str, Any], guard: TokenGuard, routes: list[BaseRoute]) -> dict[str, Any]:
    """The bearer scheme in the OpenAPI document (so /docs has *Authorize*), per operation whether it needs it, and
    the 403 of each route that needs a role (``ROUTE_ROLES``)."""
    schema.setdefault("components", {}).setdefault("securitySchemes", {}).update(SECURITY_SCHEMES)
    for route in api_routes_of(routes):
        security, role = guard.security(route), guard.needs_role(route)
        ops = schema.get("paths", {}).get(route.path_format, {})
        for method in route.methods:
            op = ops.get(method.lower())
            if op is not None and security is not None:
                op["security"] = security
            if op is not None and role is not None:
                op.setdefault("responses", {})["403"] = {"description": (
                    f"the token's role is below {role.value}: this route needs the {role.value} role (its `role` in "
                    "[api].tokens); `detail` names both")}  # fmt: skip
    return schema


def unlisted_routes(guard: TokenGuard, routes: list[BaseRoute]) -> list[str]:
    """The routes that need a role but have no line in ``ROUTE_ROLES`` (each must have one)."""
    return [f"{m} {r.path_format}" for r in api_routes_of(routes) if guard.needs_role(r) is not None
            for m in sorted(r.methods) if (m, r.path_format) not in ROUTE_ROLES]  # fmt: skip


def create_app(orch: CellOrchestrator, config: ApiConfig, jobs: JobManager | None = None) -> FastAPI:
    """The cell's HTTP face. The orchestrator (and the job manager) must be started by whoever runs the app."""
    app = FastAPI(
        title="cellctl",
        version=cellctl.__version__,
        description="Cell controller for robotic installation of large planar workpieces.",
        docs_url=None,
        redoc_url=None,
        responses=ERROR_RESPONSES,
        dependencies=[Depends(refuse_unknown_query)],  # every route: a query parameter it does not declare is a 422
    )
    guard = TokenGuard(config)
    app.state.orchestrator = orch

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = _field_errors(exc)
        return JSONResponse(status_code=422, content={"detail": _summary(errors), "errors": errors})

    routers: list[APIRouter] = [
        routes_cycles.build_router(orch, guard, config.cycle_wait_max_s),
        routes_cell.build_router(orch, guard),
        routes_quality.build_router(orch, guard),
        routes_parts.build_router(orch, guard),
    ]
    if jobs is not None:
        routers.append(routes_jobs.build_router(jobs, guard))
    for router in routers:
        app.include_router(router)
    dashboard.install(app, orch, guard)
    unlisted = unlisted_routes(guard, list(app.routes))
    if unlisted:
        raise RuntimeError(f"routes that need a token but have no role in cellctl.api.auth.ROUTE_ROLES: {unlisted}")

    # Outermost first: the body limit, then the token; both act before the application reads the body.
    api_routes = [r for router in routers for r in router.routes if isinstance(r, APIRoute)]
    app.add_middleware(TokenBeforeBody, guard=guard, routes=api_routes)
    app.add_middleware(BodySizeLimit, max_bytes=config.max_body_bytes)

    app.mount("/static/swagger-ui", StaticFiles(directory=str(swagger_ui_path)), name="swagger-ui")

    @app.get("/docs", include_in_schema=False)
    async def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url="/openapi.json",
            title="cellctl API",
            swagger_js_url="/static/swagger-ui/swagger-ui-bundle.js",
            swagger_css_url="/static/swagger-ui/swagger-ui.css",
            swagger_favicon_url="/static/swagger-ui/favicon-32x32.png",
        )  # no persistAuthorization: the token stays in the page, never in localStorage (shared HMI PCs)

    generate_openapi = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            app.openapi_schema = document_error_bodies(document_security(generate_openapi(), guard, list(app.routes)))
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
    return app
