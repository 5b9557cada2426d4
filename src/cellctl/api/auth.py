"""Bearer-token guard for mutating routes; the token's name is the actor in the audit log."""

from __future__ import annotations

import hmac
from dataclasses import dataclass

from fastapi import HTTPException, Request, status

from cellctl.config.api import ApiConfig


@dataclass(frozen=True)
class Caller:
    """Who made a request and from where (for the audit log)."""

    actor: str
    source: str


class TokenGuard:
    """Checks ``Authorization: Bearer <token>`` against the configured tokens (constant-time)."""

    def __init__(self, config: ApiConfig) -> None:
        self._tokens = [(t.name, t.secret().encode()) for t in config.tokens]
        self.open_reads = config.open_reads

    def identify(self, request: Request) -> Caller | None:
        header = request.headers.get("authorization", "")
        scheme, _, value = header.partition(" ")
        if scheme.lower() != "bearer" or not value:
            return None
        given = value.strip().encode()
        for name, secret in self._tokens:
            if hmac.compare_digest(given, secret):
                return Caller(name, _source(request))
        return None

    def require(self, request: Request) -> Caller:
        caller = self.identify(request)
        if caller is None:
            raise HTTPException(
                status.HTTP_401_UNAUTHORIZED,
                detail="this route changes the cell: send 'Authorization: Bearer <token>' with a token from [api].tokens",
                headers={"WWW-Authenticate": "Bearer"},
            )
        return caller

    def read(self, request: Request) -> Caller:
        if self.open_reads:
            return self.identify(request) or Caller("anonymous", _source(request))
        return self.require(request)


def _source(request: Request) -> str:
    return request.client.host if request.client else "unknown"
