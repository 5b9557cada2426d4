"""The alignment's record names each spot the same way: one without a reading and one rejected from the fit."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.bench.accuracy import RunSettings, run_accuracy
from cellctl.config import load_config
from cellctl.ports import DistanceReading, LaserStatus
from cellctl.sim.devices import SimDisplacementSensor

ROOT = Path(__file__).resolve().parents[2]


def test_a_rejected_spot_is_named_by_its_spot_after_one_without_a_reading(monkeypatch: pytest.MonkeyPatch) -> None:
    config = load_config(ROOT / "config" / "sim.toml")
    assert config.process.align.mode == "stop_and_go" and len(config.process.align.spots_mm) == 6
    original, reads = SimDisplacementSensor.read, [0]

    async def read(self: SimDisplacementSensor, *, timeout_s: float) -> DistanceReading:
        reads[0] += 1  # the cycle's first six reads are the alignment's spots 0 to 5
        if reads[0] == 2:  # spot 1: no return
            return DistanceReading(None, LaserStatus.OVER_RANGE_FAR, 0.0, self.head)
        r = await original(self, timeout_s=timeout_s)
        if reads[0] == 5 and r.distance_mm is not None:  # spot 4: 3 mm off the wall (a bolt head, dirt)
            return DistanceReading(r.distance_mm + 3.0, r.status, r.timestamp_s, r.head)
        return r

    monkeypatch.setattr(SimDisplacementSensor, "read", read)
    run = run_accuracy(config, RunSettings(trials=1, seed=1, calibration="oracle", devices="twin"), progress=False)
    (trial,) = run.trials
    assert trial.outcome == "done", trial.reason
    a = trial.align or {}
    assert a["spots_without_reading"] == [1]
    assert [r["index"] for r in a["rejected"]] == [4], a  # the 4th reading, spot 4


def test_three_readings_of_six_spots_are_refused_as_too_few_to_find_a_bad_one(monkeypatch: pytest.MonkeyPatch) -> None:
    config = load_config(ROOT / "config" / "sim.toml")
    original, reads = SimDisplacementSensor.read, [0]

    async def read(self: SimDisplacementSensor, *, timeout_s: float) -> DistanceReading:
        reads[0] += 1
        if reads[0] in (2, 4, 6):  # spots 1, 3 and 5 return no light: three readings are left
            return DistanceReading(None, LaserStatus.OVER_RANGE_FAR, 0.0, self.head)
        return await original(self, timeout_s=timeout_s)

    monkeypatch.setattr(SimDisplacementSensor, "read", read)
    run = run_accuracy(config, RunSettings(trials=1, seed=1, calibration="oracle", devices="twin"), progress=False)
    (trial,) = run.trials
    assert trial.outcome == "failed"
    assert "only 3 of 6 laser spots gave a distance (spots [1, 3, 5] had none; 4 are needed" in trial.reason, trial.reason


def test_every_shot_of_a_cycle_checks_the_corners_arc_against_the_openings_radius(monkeypatch: pytest.MonkeyPatch) -> None:
    """The corner method's arc check gets the opening's radius in the image's px (a second edge fits another)."""
    import cellctl.cell.cycle as cycle

    config = load_config(ROOT / "config" / "sim.toml")
    seen: list[float | None] = []
    original = cycle.detect_feature

    def detect(*args, **kwargs):  # type: ignore[no-untyped-def]
        radius = kwargs.get("corner_radius")
        seen.append(None if radius is None else radius.radius_px)
        return original(*args, **kwargs)

    monkeypatch.setattr(cycle, "detect_feature", detect)
    run = run_accuracy(config, RunSettings(trials=1, seed=1, calibration="oracle", devices="twin"), progress=False)
    assert run.trials[0].outcome == "done", run.trials[0].reason
    true_px = config.layout.opening.corner_radius_mm * config.sim.camera.intrinsics.fx / config.process.working_distance_mm
    assert len(seen) >= 2 and all(r is not None and abs(r / true_px - 1.0) < 0.01 for r in seen), (seen, true_px)
