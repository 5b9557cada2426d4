"""The REST API and dashboard server."""

from __future__ import annotations

import os

from pydantic import Field, model_validator

from cellctl.config.types import StrictModel

MIN_TOKEN_LENGTH = 16


class ApiToken(StrictModel):
    """A bearer token for mutating routes. ``name`` is the actor recorded in the audit log.

    Give the token itself (``token``) only in a file readable by the service; on a real cell name
    an environment variable instead (``token_env``), e.g. set from deploy/cellctl.env.
    """

    name: str = Field(min_length=1, max_length=64)
    token: str | None = None
    token_env: str | None = None

    @model_validator(mode="after")
    def _one_source(self) -> "ApiToken":
        if (self.token is None) == (self.token_env is None):
            raise ValueError(f"token '{self.name}': give exactly one of token or token_env")
        if self.token is not None and len(self.token) < MIN_TOKEN_LENGTH:
            raise ValueError(f"token '{self.name}': must be at least {MIN_TOKEN_LENGTH} characters")
        return self

    def secret(self) -> str:
        """The token's value (read from the environment for token_env)."""
        if self.token is not None:
            return self.token
        value = os.environ.get(self.token_env or "", "")
        if len(value) < MIN_TOKEN_LENGTH:
            raise ValueError(
                f"api token '{self.name}': environment variable {self.token_env} is unset or shorter than "
                f"{MIN_TOKEN_LENGTH} characters; set it (see deploy/cellctl.env.example)"
            )
        return value


class ApiConfig(StrictModel):
    """Where the service listens, who may change things, and whether reads need a token."""

    host: str = "127.0.0.1"
    port: int = Field(8080, ge=0, le=65535)
    tokens: tuple[ApiToken, ...] = (ApiToken(name="operator", token="sim-operator-token-change-me"),)
    open_reads: bool = True  # GET routes without a token, for a trusted cell network
    cycle_wait_max_s: float = Field(600.0, gt=0)

    @model_validator(mode="after")
    def _tokens(self) -> "ApiConfig":
        if not self.tokens:
            raise ValueError("tokens: give at least one token; mutating routes need a bearer token")
        names = [t.name for t in self.tokens]
        if len(set(names)) != len(names):
            raise ValueError(f"tokens: names must be unique, got {names}")
        return self
