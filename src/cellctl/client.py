"""A small HTTP client of the cell service for the CLI (and scripts): status, commands, cycles."""

from __future__ import annotations

import os
import time
import uuid
from typing import Any

import httpx

DEFAULT_URL = "http://127.0.0.1:8080"
TOKEN_ENV = "CELLCTL_TOKEN"


class ServiceError(RuntimeError):
    """The service answered with an error (the message carries its detail) or could not be reached."""


class CellClient:
    """Talks to a running ``cellctl serve``. ``token`` defaults to $CELLCTL_TOKEN."""

    def __init__(self, url: str = DEFAULT_URL, token: str | None = None, timeout_s: float = 30.0) -> None:
        self.url = url.rstrip("/")
        self._token = token if token is not None else os.environ.get(TOKEN_ENV)
        self._http = httpx.Client(base_url=self.url, timeout=timeout_s)

    def close(self) -> None:
        self._http.close()

    def _headers(self, extra: dict[str, str] | None = None) -> dict[str, str]:
        h = dict(extra or {})
        if self._token:
            h["Authorization"] = f"Bearer {self._token}"
        return h

    def _call(self, method: str, path: str, **kw: Any) -> Any:
        try:
            r = self._http.request(method, path, **kw)
        except httpx.HTTPError as err:
            raise ServiceError(f"cannot reach the cell service at {self.url}: {err} (is `cellctl serve` running?)") from None
        if r.status_code >= 400:
            try:
                detail = r.json().get("detail", r.text)
            except ValueError:
                detail = r.text
            raise ServiceError(f"{method} {path} -> {r.status_code}: {detail}")
        return r.json()

    def status(self) -> dict[str, Any]:
        return self._call("GET", "/status")

    def command(self, name: str) -> dict[str, Any]:
        return self._call("POST", f"/commands/{name}", headers=self._headers())

    def start_cycle(
        self, recipe: str, part_id: str, *, key: str | None = None, wait: bool = True, timeout_s: float = 300.0
    ) -> dict[str, Any]:
        headers = self._headers({"Idempotency-Key": key or uuid.uuid4().hex})
        params = {"wait": str(wait).lower(), "timeout_s": timeout_s}
        return self._call(
            "POST", "/cycle", json={"recipe": recipe, "part_id": part_id}, headers=headers, params=params,
            timeout=timeout_s + 10.0,
        )  # fmt: skip

    def cycle(self, cycle_id: int) -> dict[str, Any]:
        return self._call("GET", f"/cycles/{cycle_id}")

    def bring_to_execute(self) -> str:
        """Send Clear/Reset/Start as the state needs to reach Execute; returns the state reached."""
        plan = {"ABORTED": ["clear", "reset", "start"], "STOPPED": ["reset", "start"], "COMPLETE": ["reset", "start"],
                "IDLE": ["start"], "HELD": ["unhold"], "SUSPENDED": ["unsuspend"]}  # fmt: skip
        state = self.status()["state"]
        for cmd in plan.get(state, []):
            self.command(cmd)
            state = self.wait_settled()
        return state

    def wait_settled(self, timeout_s: float = 30.0) -> str:
        """Wait until the cell leaves its acting state (Clearing, Resetting, Starting, ...)."""
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.status()["state"]
            if not state.endswith("ING") or time.monotonic() > deadline:
                return state
            time.sleep(0.05)
