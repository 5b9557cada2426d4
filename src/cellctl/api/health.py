"""What ``GET /health`` decides: is the cell ready to work (HTTP 200) or not (HTTP 503), and why.

Not healthy (503), each with a line in ``problems``:

- the service is stopping (SIGTERM or Ctrl-C arrived: a load balancer should stop sending now);
- the store does not answer within :data:`STORE_ANSWER_S` (closed, the database fails, or busy: another process holds
  its lock and the cell's writes wait for it);
- alarm 1703 is active: the store refused a write, kept in memory until it takes it (production is held meanwhile);
- a device link is ``lost`` (the watchdog missed it ``miss_threshold`` times in a row; ``unknown``
  before its first ping and ``degraded`` after a single miss do not count);
- the PLC link ``lost``, when ``[plc] enabled`` and ``[plc] heartbeat_alarm`` are on (a line cell; a
  simulated cell without a PLC runs with the alarm off, and its PLC link never counts). A PLC that
  has not sent its first heartbeat yet is ``waiting``, which counts as healthy, for
  ``heartbeat_timeout_s`` after the PLC server started: then the interface reports the link lost
  (alarm 1201 with the alarm on), as if it had stopped, and so does /health until the PLC beats.
"""

from __future__ import annotations

import asyncio
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from cellctl.cell.orchestrator import CellOrchestrator
from cellctl.domain import AlarmCode

STORE_ANSWER_S = 1.0
"""Seconds /health waits for the store to answer (a probe's timeout is often 1-5 s: it gets the reason, not a hang)."""


@dataclass
class HealthVerdict:
    """The outcome: ``ok`` with the details /health shows."""

    ok: bool
    devices_lost: list[str]
    plc: str | None
    problems: list[str] = field(default_factory=list)
    journal_mode: str | None = None


def plc_problem(report: Mapping[str, Any] | None, *, counts: bool) -> str | None:
    """Why the PLC link makes the cell unhealthy, or None. ``counts``: ``[plc] enabled`` and ``heartbeat_alarm`` are on."""
    if not counts or report is None or report.get("link") != "lost":
        return None  # up, or waiting for the first heartbeat (lost after heartbeat_timeout_s without one)
    silent = report.get("silent_for_s")
    return "the PLC link is lost" + (f" (no heartbeat for {silent} s)" if silent is not None else "")


async def judge(orch: CellOrchestrator) -> HealthVerdict:
    """The cell's health as of now (reads the store once, to see that it answers)."""
    status = orch.status()
    problems: list[str] = []
    if orch.events.closing:
        problems.append("the service is stopping")
    lost = sorted(name for name, d in status["devices"].items() if d["link"] == "lost")
    problems += [f"device {name}: link lost (the watchdog no longer hears it)" for name in lost]
    plc_cfg = orch.config.plc
    report = status["links"].get("plc")
    plc_state = None if not plc_cfg.enabled else ("waiting" if report is None else str(report["link"]))
    why = plc_problem(report, counts=plc_cfg.enabled and plc_cfg.heartbeat_alarm)
    if why is not None:
        problems.append(why)
    journal_mode = None
    try:
        journal_mode = (await asyncio.wait_for(orch.store.info(), STORE_ANSWER_S)).journal_mode
    except TimeoutError:  # queued behind writes that wait for another process's lock (busy_timeout_s each)
        problems.append(f"the store does not answer (busy for over {STORE_ANSWER_S:g} s: another process may hold its lock)")
    except Exception as err:  # noqa: BLE001 - any failure of the store is the answer here
        problems.append(f"the store does not answer ({type(err).__name__})")  # not its message: it may name the path
    if any(a.code == AlarmCode.RECORD_WRITE_FAILED and a.active for a in orch.alarms.current()):
        problems.append("the store refuses writes: records kept in memory until it takes them (alarm 1703)")
    return HealthVerdict(ok=not problems, devices_lost=lost, plc=plc_state, problems=problems, journal_mode=journal_mode)

