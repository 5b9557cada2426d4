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
