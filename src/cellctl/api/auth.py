"""Bearer-token guard: mutating routes need a token, reads too with ``[api] open_reads = false``; the token's name is the actor in the audit log."""

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

from cellctl.config.api import ApiConfig

SECURITY_SCHEME = "bearerToken"
"""The OpenAPI security scheme's name (HTTP bearer): /docs offers it under *Authorize*."""
SECURITY_SCHEMES = {
    SECURITY_SCHEME: {
        "type": "http",
        "scheme": "bearer",
        "description": "a token of [api].tokens (its name is the actor in the audit log); the operator's of the "
        "simulated cell is in config/sim.toml",
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


@dataclass(frozen=True)
class Caller:
    """Who made a request and from where (for the audit log)."""

    actor: str
    source: str


class TokenGuard:
    """Checks ``Authorization: Bearer <token>`` against the configured tokens (constant-time).

    The tokens are read once, here (environment variables and files at the time the app is built);
    ``cellctl serve`` has checked before it started anything that they can be read.
    """

    def __init__(self, config: ApiConfig) -> None:
        self._tokens = [(name, secret.encode()) for name, secret in config.secrets()]
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
        return None if name is None else Caller(name, _source(request))

    def require(self, request: Request) -> Caller:
        """The caller of a mutating route: a valid bearer token, or 401."""
        caller = self.identify(request)
        if caller is None:
            detail = unauthorized_detail(request.headers.get("authorization", ""))
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, detail=detail, headers={"WWW-Authenticate": "Bearer"})
        return caller

    def read(self, request: Request) -> Caller:
        """The caller of a read: anyone with open reads (``anonymous`` without a token), else a token holder."""
        if self.open_reads:
            return self.identify(request) or Caller("anonymous", _source(request))
        return self.require(request)

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
    """ASGI middleware: a request to a route that needs a token is answered 401 before its body is read.

    FastAPI reads and parses a route's body before it solves the route's dependencies, so the
    ``Depends(guard.require)`` of a mutating route would see the token only after the whole body
    was in memory. This checks the same token on the headers alone; the dependency still runs
    (it names the caller).
    """

    def __init__(self, app: ASGIApp, guard: TokenGuard, routes: list[BaseRoute]) -> None:
        self.app = app
        self.guard = guard
        self.routes = routes  # the application's route list (routes added later are seen too)
        self._needs: dict[int, bool] = {}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or not self._route_needs_token(scope):
            await self.app(scope, receive, send)
            return
        authorization = Headers(scope=scope).get("authorization", "")
        if self.guard.actor_for(authorization) is None:
            response = JSONResponse(
                {"detail": unauthorized_detail(authorization)}, status_code=status.HTTP_401_UNAUTHORIZED,
                headers={"WWW-Authenticate": "Bearer"},
            )  # fmt: skip
            await response(scope, receive, send)
            return
        await self.app(scope, receive, send)

    def _route_needs_token(self, scope: Scope) -> bool:
        for route in self.routes:
            match, _ = route.matches(scope)
            if match is Match.FULL:
                key = id(route)
                if key not in self._needs:
                    self._needs[key] = self.guard.needs_token(route)
                return self._needs[key]
        return False


def _dependencies(dependant: Dependant) -> Iterator[Dependant]:
    for d in dependant.dependencies:
        yield d
        yield from _dependencies(d)


def _source(request: Request) -> str:
    return request.client.host if request.client else "unknown"
