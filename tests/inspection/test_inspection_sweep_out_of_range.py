"""Flush on the move with readings beyond the configured laser range: left out and counted, not a software fault.

The twin's beam through the gap meets the body's flange 60 mm behind the wall: inside the head's
range, outside ``process.align.laser_range_mm = [300, 400]``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import cellctl.cell.inspect_step as inspect_step
import cellctl.sim.laser as sim_laser
from cellctl.bench.accuracy import RunSettings, run_accuracy
from cellctl.config import load_config

ROOT = Path(__file__).resolve().parents[2]


def test_a_reading_through_the_gap_beyond_the_range_is_left_out_and_counted(monkeypatch: pytest.MonkeyPatch) -> None:
    hit = sim_laser.LaserModel._hit

    def through_the_gap(self: Any, T: Any, world: Any, glass: Any) -> Any:
        d, on_glass = hit(self, T, world, glass)
        if d is None and glass is not None:  # the gap: the flange behind the wall
            origin, direction = self.beam(T)
            dw = world.ray_hit(origin, direction)[0]
            return (350.0 if dw is None else dw) + 60.0, False
        return d, on_glass

    monkeypatch.setattr(sim_laser.LaserModel, "_hit", through_the_gap)
    figures: list[dict[str, Any]] = []
    sweep = inspect_step.sweep_flush

    async def recorded(run: Any, T2: Any) -> Any:
        flush, f = await sweep(run, T2)
        figures.append(f)
        return flush, f

    monkeypatch.setattr(inspect_step, "sweep_flush", recorded)
    cfg = load_config(ROOT / "config" / "sim.toml")
    p = cfg.process
    align = p.align.model_copy(update={"mode": "on_the_fly", "laser_range_mm": (300.0, 400.0)})
    cfg = cfg.model_copy(update={"process": p.model_copy(update={"align": align})})
    (trial,) = run_accuracy(cfg, RunSettings(trials=1, seed=3, calibration="oracle", devices="twin"), progress=False).trials
    assert trial.outcome == "done", trial.reason
    assert (trial.align or {}).get("mode") == "on_the_fly"
    assert figures and figures[0]["readings_out_of_range"] > 0
