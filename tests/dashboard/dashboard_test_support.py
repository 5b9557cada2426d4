"""The simulated cell service with its HTTP server on a free loopback port, for the dashboard tests.

The service runs in a background thread with its own asyncio loop (:class:`live_cell.LiveCell`: the
real composition from ``build_service`` and the real ``create_app`` under uvicorn), so a test can
drive it over HTTP like any client, drive a headless Chromium at it, and still reach into the
orchestrator (e.g. to raise an alarm at a chosen moment) through :meth:`LiveCell.run`.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
from live_cell import LiveCell  # noqa: F401  (the dashboard tests import it from here)
from service_test_support import sim_config as service_sim_config
from shared_support import on_ci

from cellctl.config import CellConfig

ROOT = Path(__file__).resolve().parents[2]
TOKEN = "sim-operator-token-change-me"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
ARTIFACTS = ROOT / "test-artifacts" / "dashboard"
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
LOOPBACK_HOSTS = {"127.0.0.1", "localhost", "[::1]", "::1"}


def sim_config(**sections: dict[str, Any]) -> CellConfig:
    """The service harness's config with the PLC server off by default (no port to clash)."""
    sections.setdefault("plc", {"enabled": False})
    return service_sim_config(**sections)


def chromium_missing_reason() -> str | None:
    """Why the browser tests cannot run here, or None. On CI (CI=true) a missing browser is a failure."""
    if CHROMIUM.is_file() and shutil.which(str(CHROMIUM)):
        return None
    reason = f"{CHROMIUM} is missing: install Debian's chromium (apt-get install -y chromium)"
    if on_ci():
        raise RuntimeError(reason + " (CI must install it)")
    return reason


def browser_marks(timeout_s: float = 120) -> list[Any]:
    """A browser test module's marks: skipped without Chromium (off CI), and a time limit."""
    import pytest

    missing = chromium_missing_reason()
    return [pytest.mark.skipif(missing is not None, reason=missing or ""), pytest.mark.timeout(timeout_s)]


def settle(client: httpx.Client, deadline_s: float = 10.0) -> str:
    """The PackML state once the acting states (..ING) have ended."""
    end = time.monotonic() + deadline_s
    while True:
        state = str(client.get("/status").json()["state"])
        if not state.endswith("ING") or time.monotonic() > end:
            return state
        time.sleep(0.02)


RECOVERY = {"ABORTED": "clear", "STOPPED": "reset", "IDLE": "start", "HELD": "unhold", "SUSPENDED": "unsuspend", "COMPLETE": "reset"}


def to_execute(client: httpx.Client) -> None:
    """Bring the cell to Execute from wherever it is, acknowledging alarms on the way."""
    for _ in range(8):
        state = settle(client)
        if state == "EXECUTE":
            return
        client.post("/alarms/acknowledge-all", headers=AUTH).raise_for_status()
        r = client.post(f"/commands/{RECOVERY[state]}", headers=AUTH)
        assert r.status_code == 200, r.text
    raise AssertionError(f"the cell did not reach EXECUTE, it is {settle(client)}")


def to_aborted(client: httpx.Client) -> None:
    if settle(client) != "ABORTED":
        assert client.post("/commands/abort", headers=AUTH).status_code == 200
    assert settle(client) == "ABORTED"


def install_cycles(client: httpx.Client, key: str, parts: list[tuple[str, str | None]]) -> list[dict[str, Any]]:
    """Run one cycle per (part id, car id) to its end (``wait=true``); each must install. Their records."""
    to_execute(client)
    out = []
    for i, (part_id, car_id) in enumerate(parts):
        body: dict[str, Any] = {"recipe": "side-window", "part_id": part_id}
        if car_id is not None:
            body["car_id"] = car_id
        r = client.post(
            "/cycle", params={"wait": "true", "timeout_s": 60}, json=body, headers={**AUTH, "Idempotency-Key": f"{key}-{i}"}
        )
        assert r.status_code == 200, r.text
        assert r.json()["state"] == "done", r.json()
        out.append(dict(r.json()))
    return out


def wait_cycle(client: httpx.Client, cycle_id: int, deadline_s: float = 30.0) -> dict[str, Any]:
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        rec = client.get(f"/cycles/{cycle_id}").json()
        if rec["state"] in ("done", "failed", "interrupted"):
            return dict(rec)
        time.sleep(0.05)
    raise AssertionError(f"cycle {cycle_id} did not finish within {deadline_s} s")


class PageLog:
    """Every request the page made, what the browser console reported as an error, and full page loads."""

    def __init__(self) -> None:
        self.requests: list[str] = []
        self.errors: list[str] = []
        self.loads = 0  # full document loads (hash changes do not count)

    def foreign(self) -> list[str]:
        return [u for u in self.requests if urlsplit(u).scheme not in ("data", "blob") and urlsplit(u).hostname not in LOOPBACK_HOSTS]


def shot(pg: Any, name: str) -> Path:
    """A full-page screenshot into test-artifacts/dashboard/."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    path = ARTIFACTS / name
    pg.screenshot(path=str(path), full_page=True)
    return path
