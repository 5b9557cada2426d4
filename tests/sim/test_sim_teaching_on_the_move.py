"""Teaching for the cycle on the move against the twin's truth: the robot's accuracy field leaves the install alone.

The cycle on the move takes the wall's normal along its sweep and the offset at the sweep's corners, where
the robot's absolute-accuracy error differs from the mean over the path. Taught the same way (the oracle's
teaching, as the commissioning procedure's), that error cancels between teaching and cycle; taught from all
spots, it put every install about 0.03 mm deep on three twins.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cellctl.bench.accuracy import RunSettings, run_accuracy
from cellctl.bench.cycle_time import with_align_mode
from cellctl.bench.sources import ERROR_SOURCES
from cellctl.config import CellConfig, load_config
from cellctl.ports import DistanceReading, LaserStatus
from cellctl.sim.devices import SimDisplacementSensor, SimRobot

ROOT = Path(__file__).resolve().parents[2]


def test_on_the_move_the_robots_accuracy_field_leaves_the_installs_depth_alone() -> None:
    base = with_align_mode(load_config(ROOT / "config" / "sim.toml"), "on_the_fly")
    process = base.process.model_copy(update={"spc": base.process.spc.model_copy(update={"enabled": False})})
    config = base.model_copy(update={"process": process})  # no closed loop: each install shows its own error
    off = tuple(n for n in ERROR_SOURCES if n != "robot_accuracy")
    run = run_accuracy(config, RunSettings(trials=4, seed=1, off=off, calibration="oracle", devices="twin"), progress=False)
    assert len(run.installed) == 4 and all((t.align or {}).get("mode") == "on_the_fly" for t in run.installed)
    dz = np.array([t.true_error["dz_mm"] for t in run.installed if t.true_error])
    assert abs(dz.mean()) < 0.012, dz  # taught from all the spots: +0.027 on this twin


def _without_stream(monkeypatch: pytest.MonkeyPatch) -> CellConfig:
    """A cell configured to read on the move whose controller has no EGM: the twin's robot streams no pose."""
    monkeypatch.setattr(SimRobot, "stream_unavailable", lambda self: "no position feedback stream on this controller")
    base = with_align_mode(load_config(ROOT / "config" / "sim.toml"), "on_the_fly")
    process = base.process.model_copy(update={"spc": base.process.spc.model_copy(update={"enabled": False})})
    return base.model_copy(update={"process": process})


def test_a_cell_taught_for_the_move_whose_robot_cannot_stream_reads_standing_where_it_was_taught(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    config = _without_stream(monkeypatch)  # the cycle falls back to reading standing, at teaching's places
    align = config.process.align
    off = tuple(n for n in ERROR_SOURCES if n != "robot_accuracy")
    run = run_accuracy(config, RunSettings(trials=4, seed=1, off=off, calibration="oracle", devices="twin"), progress=False)
    assert len(run.installed) == 4
    for t in run.installed:
        a = t.align or {}
        assert a.get("mode") == "stop_and_go" and "no position feedback" in a.get("on_the_fly_unavailable", ""), a
        assert a["spots_along"] == "process.align.sweep.path_mm" and a["stops"] == list(align.wall_stops()), a
    dz = np.array([t.true_error["dz_mm"] for t in run.installed if t.true_error])
    assert abs(dz.mean()) < 0.012, dz  # reading the six spots of process.align.spots_mm instead: about +0.03


def test_without_a_reading_at_a_corner_the_fallback_refuses_rather_than_take_the_distance_elsewhere(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    config = _without_stream(monkeypatch)
    corner = config.process.align.wall_stops()[1]  # the path's second corner, among the points along it
    original, reads = SimDisplacementSensor.read, [0]

    async def read(self: SimDisplacementSensor, *, timeout_s: float) -> DistanceReading:
        reads[0] += 1
        if reads[0] == corner + 1:  # the cycle's reads are the alignment's, in the order of the points
            return DistanceReading(None, LaserStatus.OVER_RANGE_FAR, 0.0, self.head)
        return await original(self, timeout_s=timeout_s)

    monkeypatch.setattr(SimDisplacementSensor, "read", read)
    run = run_accuracy(config, RunSettings(trials=1, seed=1, calibration="oracle", devices="twin"), progress=False)
    (trial,) = run.trials
    assert trial.outcome == "failed" and f"no laser reading at spots [{corner}], corners of process.align.sweep.path_mm" in (
        trial.reason or ""
    ), trial
