"""`cellctl bench opcua` pairs every change of the cell with the encrypted client's notification of it."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.bench.opcua_latency import format_opcua_latency, run_opcua_latency
from cellctl.config import load_config

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.timeout(180)


def test_every_state_and_step_change_reaches_the_client() -> None:
    figures = run_opcua_latency(load_config(ROOT / "config" / "sim.toml"), holds=2, cycles=1, publish_ms=10.0)
    state, steps = figures["state"], figures["cycle_step"]
    # Two Hold/Unhold pairs: Holding, Held, Unholding, Execute twice each; every one was seen, none twice.
    assert state["changes"] == 8, figures
    assert steps["changes"] >= 6, figures  # calibrate .. inspect, then none
    assert state["changes"] + steps["changes"] == figures["changes_made"] == figures["notifications"], figures
    assert 0.0 <= state["median_ms"] <= state["max_ms"]
    assert "StateCurrent" in format_opcua_latency(figures)
