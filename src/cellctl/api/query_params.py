"""Unknown query parameters are refused (422 naming them), so a misspelled filter never returns unfiltered data."""

from __future__ import annotations

from collections.abc import Iterator

from fastapi import Request
from fastapi.dependencies.models import Dependant
from fastapi.exceptions import RequestValidationError
from fastapi.routing import APIRoute


def declared_query(route: APIRoute) -> frozenset[str]:
    """The query parameter names ``route`` declares, its dependencies' included (aliases as sent)."""
    return frozenset(_query_names(route.dependant))


def _query_names(dependant: Dependant) -> Iterator[str]:
    yield from (p.alias for p in dependant.query_params)
    for sub in dependant.dependencies:
        yield from _query_names(sub)


async def refuse_unknown_query(request: Request) -> None:
    """App dependency: a route that takes query parameters refuses any it does not declare, naming each and the known ones."""
    route = request.scope.get("route")
    if not isinstance(route, APIRoute):
        return
    known = declared_query(route)
    if not known:
        return  # a route without query parameters has no filter to misspell
    unknown = sorted({name for name in request.query_params if name not in known})
    if unknown:
        hint = f"unknown query parameter; {route.path} takes {', '.join(sorted(known))}"
        raise RequestValidationError(
            [{"type": "unknown_parameter", "loc": ("query", name), "msg": hint, "input": request.query_params[name]} for name in unknown]
        )
