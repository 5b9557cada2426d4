"""Bearer-token guard: mutating routes need a token of the role ``ROUTE_ROLES`` names, reads any token with
``[api] open_reads = false``; the token's name is the actor in the audit log."""

from __future__ import annotations

import hmac
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from fastapi import Depends, HTTPException, Request, status
from fastapi.dependencies.models import Dependant
from fastapi.params import Depends as DependsParam
from fastapi.routing import APIRoute
from starlette.datastructures import Headers
from starlette.responses import JSONResponse
from starlette.routing import BaseRoute, Match
from starlette.types import ASGIApp, Receive, Scope, Send

from cellctl.config.api import ApiConfig, ApiRole

ROUTE_ROLES: dict[tuple[str, str], ApiRole] = {
    ("POST", "/cycle"): ApiRole.operator,
    ("POST", "/commands/{name}"): ApiRole.operator,
    ("POST", "/alarms/{uid}/acknowledge"): ApiRole.operator,
    ("POST", "/alarms/acknowledge-all"): ApiRole.operator,
    ("POST", "/mode/{name}"): ApiRole.operator,  # as OPC UA's operator may call SetUnitMode
    ("POST", "/spc/reset"): ApiRole.engineer,
    ("POST", "/jobs"): ApiRole.engineer,
    ("POST", "/jobs/{job_id}/cancel"): ApiRole.engineer,
    ("POST", "/jobs/{job_id}/prompts/{prompt_id}"): ApiRole.engineer,
}
"""The role each mutating route needs, by (method, path): the one table of who may change what. Reads need
no role (any token where reads are closed); a guarded route missing here needs ``engineer`` (the app refuses to build)."""

SECURITY_SCHEME = "bearerToken"
"""The OpenAPI security scheme's name (HTTP bearer): /docs offers it under *Authorize*."""
SECURITY_SCHEMES = {
    SECURITY_SCHEME: {
        "type": "http",
        "scheme": "bearer",
        "description": "a token of [api].tokens (its name is the actor in the audit log); its role (viewer, operator, "
        "engineer) decides which mutating routes it may use, a lower one gets 403; config/sim.toml has the simulated "
        "cell's tokens",
    }
}

UNAUTHORIZED_DETAIL = (
    "this route needs a bearer token: send 'Authorization: Bearer <token>' with a token from [api].tokens"
)
WRONG_TOKEN_DETAIL = (
    "the token sent is not one of [api].tokens (or the header is not 'Authorization: Bearer <token>'): "
    "send a token configured there"
)


def unauthorized_detail(authorization: str) -> str:
    """The 401's detail: no Authorization header at all, or one whose token is not accepted."""
    return WRONG_TOKEN_DETAIL if authorization.strip() else UNAUTHORIZED_DETAIL


def forbidden_detail(route: str, name: str, role: ApiRole, needed: ApiRole) -> str:
    """The 403's detail: the role ``route`` needs, the token's role, and the two ways out."""
    holders = " or ".join(f"{'an' if r.value[0] in 'aeiou' else 'a'} {r.value}'s" for r in ApiRole if r.allows(needed))
    return (f"{route} needs the {needed.value} role; token '{name}' is {role.value}: use {holders} token, "
            "or change the token's role in [api].tokens")


def route_role(route: BaseRoute) -> ApiRole:
    """The role a guarded ``route`` needs (``ROUTE_ROLES``; engineer when it is missing there)."""
    path, methods = getattr(route, "path_format", ""), getattr(route, "methods", None) or {"POST"}
    found = [ROUTE_ROLES.get((m.upper(), path), ApiRole.engineer) for m in methods]
    return max(found, key=list(ApiRole).index)


@dataclass(frozen=True)
class Caller:
    """Who made a request and from where (for the audit log)."""

    actor: str
    source: str
    role: ApiRole | None = None  # None: no token (an open read)


class TokenGuard:
    """Checks ``Authorization: Bearer <token>`` against the configured tokens (constant-time).

    The tokens are read once, here (environment variables and files at the time the app is built);
    ``cellctl serve`` has checked before it started anything that they can be read.
    """

    def __init__(self, config: ApiConfig) -> None:
        self._tokens = [(name, secret.encode()) for name, secret in config.secrets()]
        self._roles = config.roles()
        self.open_reads = config.open_reads

    def actor_for(self, authorization: str) -> str | None:
        """The name of the token in an Authorization header value (None: no valid bearer token)."""
        scheme, _, value = authorization.partition(" ")
        if scheme.lower() != "bearer" or not value.strip():
            return None
        given = value.strip().encode()
        found = None
        for name, secret in self._tokens:
            if hmac.compare_digest(given, secret) and found is None:
                found = name
        return found

    def identify(self, request: Request) -> Caller | None:
        name = self.actor_for(request.headers.get("authorization", ""))
        return None if name is None else Caller(name, _source(request), self._roles[name])

    def authenticate(self, request: Request) -> Caller:
        """The caller: a valid bearer token (any role), or 401."""
        caller = self.identify(request)
        if caller is None:
            detail = unauthorized_detail(request.headers.get("authorization", ""))
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, detail=detail, headers={"WWW-Authenticate": "Bearer"})
        return caller

    def require(self, request: Request) -> Caller:
        """The caller of a mutating route: a valid bearer token (else 401) of the role ``ROUTE_ROLES`` names (else 403)."""
        caller = self.authenticate(request)
        route = request.scope.get("route")
        needed = route_role(route) if route is not None else ApiRole.engineer
        problem = self.refusal(caller.actor, needed, f"{request.method} {getattr(route, 'path_format', request.url.path)}")
        if problem is not None:
            raise HTTPException(status.HTTP_403_FORBIDDEN, detail=problem)
        return caller

    def refusal(self, name: str, needed: ApiRole, route: str) -> str | None:
        """Why token ``name`` may not use ``route`` (the 403's detail), or None: its role allows it."""
        role = self._roles[name]
        return None if role.allows(needed) else forbidden_detail(route, name, role, needed)

    def read(self, request: Request) -> Caller:
        """The caller of a read: anyone with open reads (``anonymous`` without a token), else a token holder."""
        if self.open_reads:
            return self.identify(request) or Caller("anonymous", _source(request))
        return self.authenticate(request)

    def reads(self) -> list[DependsParam]:
        """``dependencies=`` of a router of reads: :meth:`read` runs before each of its handlers (401 when closed)."""
        return [Depends(self.read)]

    def may_read_details(self, request: Request) -> bool:
        """Reads are open, or the request carries a valid token (e.g. /health's details)."""
        return self.open_reads or self.identify(request) is not None

    def needs_token(self, route: BaseRoute) -> bool:
        """Whether ``route`` refuses a request without a token: it depends on ``require`` (or on ``read`` with closed reads)."""
        if not isinstance(route, APIRoute):
            return False
        guards: list[Callable[..., Any]] = [self.require] if self.open_reads else [self.require, self.read]
        return any(d.call in guards for d in _dependencies(route.dependant))

    def needs_role(self, route: BaseRoute) -> ApiRole | None:
        """The role ``route`` needs of a token (``ROUTE_ROLES``), or None: any token, or none, will do."""
        if not isinstance(route, APIRoute) or not any(d.call == self.require for d in _dependencies(route.dependant)):
            return None
        return route_role(route)

    def security(self, route: BaseRoute) -> list[dict[str, list[str]]] | None:
        """The OpenAPI ``security`` of ``route``: the token required, optional (an open read) or None (not guarded)."""
        if not isinstance(route, APIRoute):
            return None
        if self.needs_token(route):
            return [{SECURITY_SCHEME: []}]
        if any(d.call == self.read for d in _dependencies(route.dependant)):
            return [{}, {SECURITY_SCHEME: []}]  # anyone may read; a token names the caller
        return None


class TokenBeforeBody:
    """ASGI middleware: a request to a route that needs a token is answered 401 (or 403: too low a role) before its body is read.

    FastAPI reads and parses a route's body before it solves the route's dependencies, so the
    ``Depends(guard.require)`` of a mutating route would see the token only after the whole body
    was in memory. This checks the same token on the headers alone; the dependency still runs
    (it names the caller).
    """

    def __init__(self, app: ASGIApp, guard: TokenGuard, routes: list[BaseRoute]) -> None:
        self.app = app
        self.guard = guard
        self.routes = routes  # the application's route list (routes added later are seen too)
        self._needs: dict[int, tuple[bool, ApiRole | None]] = {}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        route = self._route(scope) if scope["type"] == "http" else None
        needs_token, role = self._needs_of(route) if route is not None else (False, None)
        if not needs_token:
            await self.app(scope, receive, send)
            return
        authorization = Headers(scope=scope).get("authorization", "")
        name = self.guard.actor_for(authorization)
        if name is None:
            response = JSONResponse(
                {"detail": unauthorized_detail(authorization)}, status_code=status.HTTP_401_UNAUTHORIZED,
                headers={"WWW-Authenticate": "Bearer"},
            )  # fmt: skip
            await response(scope, receive, send)
            return
        problem = None if role is None else self.guard.refusal(name, role, f"{scope['method']} {getattr(route, 'path_format', '')}")
        if problem is not None:
            await JSONResponse({"detail": problem}, status_code=status.HTTP_403_FORBIDDEN)(scope, receive, send)
            return
        await self.app(scope, receive, send)

    def _route(self, scope: Scope) -> BaseRoute | None:
        return next((r for r in self.routes if r.matches(scope)[0] is Match.FULL), None)

    def _needs_of(self, route: BaseRoute) -> tuple[bool, ApiRole | None]:
        key = id(route)
        if key not in self._needs:
            self._needs[key] = (self.guard.needs_token(route), self.guard.needs_role(route))
        return self._needs[key]


def _dependencies(dependant: Dependant) -> Iterator[Dependant]:
    for d in dependant.dependencies:
        yield d
        yield from _dependencies(d)


def _source(request: Request) -> str:
    return request.client.host if request.client else "unknown"
