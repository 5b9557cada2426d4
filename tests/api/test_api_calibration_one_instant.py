"""One calibration document, one instant: ``GET /calibration`` and ``/status`` reckon every verdict they hold (the
first recipe's ``problems`` and each recipe's) at the same time, so a part expiring while the document is built
cannot make its lines disagree (as in a full run of the suite: the top-level problems said "camera: expired" and
every recipe "ready"). The time that passes while the document is built is made a second here: the clock the calibration set
reads stands just before the camera's recorded expiry and steps past it after the first verdict. Truth: the
camera's expiry as the test recorded it, against the document's own ``now_utc``.
"""

from __future__ import annotations

from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import httpx
import pytest
from calibration_set_support import CELL_PARTS, RECIPE_PARTS, commit
from live_cell import LiveCell
from service_test_support import sim_config

import cellctl.calibration.source as source_module
from cellctl.calibration.calibration_set import CalibrationStore
from cellctl.calibration.source import CalibrationSetSource


class SteppingClock:
    """``datetime`` for the calibration set: stands at ``at`` until told to step (then at ``at`` + ``step``)."""

    def __init__(self, at: datetime, step: timedelta) -> None:
        self.at, self.step = at, step

    def now(self, tz: Any = None) -> datetime:
        return self.at

    def stepped(self) -> None:
        self.at += self.step

    def __getattr__(self, name: str) -> Any:
        return getattr(datetime, name)


@pytest.fixture()
def cell(tmp_path: Path) -> Iterator[tuple[LiveCell, datetime]]:
    """The simulated cell on a ready set whose camera expires in an hour; the camera's expiry."""
    store = CalibrationStore(tmp_path / "calibration")
    at = datetime.now(timezone.utc) - timedelta(days=1)
    expires = at + timedelta(days=1, hours=1)
    commit(store, ("camera",), None, at, valid_days=(expires - at) / timedelta(days=1))
    commit(store, CELL_PARTS[1:], None, at)
    commit(store, RECIPE_PARTS, "door-window", at)
    cfg = sim_config(calibration={"source": "set", "auto_calibrate_in_sim": False, "directory": str(store.root)})
    with LiveCell(tmp_path / "cell", cfg) as live:
        yield live, expires


def test_a_part_expiring_while_a_document_is_built_splits_no_verdicts(
    cell: tuple[LiveCell, datetime], monkeypatch: pytest.MonkeyPatch
) -> None:
    live, expires = cell
    clock = SteppingClock(expires - timedelta(milliseconds=1), timedelta(seconds=1))
    monkeypatch.setattr(source_module, "datetime", clock)  # what the set reads when given no instant
    monkeypatch.setattr("cellctl.api.routes_cell.datetime", clock)  # the document's instant
    monkeypatch.setattr("cellctl.cell.recipe_gate.datetime", clock, raising=False)  # it read no clock before
    summary, problems = CalibrationSetSource.summary, CalibrationSetSource.problems

    def slow_summary(self: CalibrationSetSource, **kw: Any) -> dict[str, Any]:
        try:
            return summary(self, **kw)
        finally:
            clock.stepped()  # the second the document took to build: past the camera's expiry

    monkeypatch.setattr(CalibrationSetSource, "summary", slow_summary)
    with httpx.Client(base_url=live.url, timeout=15.0) as client:
        doc = client.get("/calibration").json()
        now = datetime.fromisoformat(doc["now_utc"])
        assert now < expires  # the document's instant: the camera still valid, in every line it holds
        assert doc["problems"] == [], doc["problems"]
        assert all(r["ready"] and r["problems"] == [] for r in doc["current"]["recipes"].values()), doc["current"]["recipes"]

        # /status: each recipe's verdict, then the first recipe's, with the clock stepping past the expiry between.
        clock.at = expires - timedelta(milliseconds=1)
        calls = {"n": 0}

        def slow_problems(self: CalibrationSetSource, recipe: str | None = None, **kw: Any) -> list[str]:
            try:
                return problems(self, recipe, **kw)
            finally:
                calls["n"] += 1
                if calls["n"] == 1:
                    clock.stepped()

        monkeypatch.setattr(CalibrationSetSource, "problems", slow_problems)
        status = client.get("/status").json()["calibration"]
        assert calls["n"] >= 2, calls
        expired = [bool(status["problems"])] + [bool(r["problems"]) for r in status["recipes"].values()]
        assert len(set(expired)) == 1, status  # all expired or none: one instant
