"""A latency off by milliseconds on the move: the path's passes part, the fit refuses, and the reason names the latency."""

from __future__ import annotations

from pathlib import Path

from cellctl.bench.accuracy import RunSettings, run_accuracy
from cellctl.bench.cycle_time import with_align_mode
from cellctl.config import load_config

ROOT = Path(__file__).resolve().parents[2]


# 20 ms at the alignment sweep's 500 mm/s (the glass's travel speed) pairs each reading 10 mm along the path from its pose.
OFF_S = 0.020


def test_a_latency_20_ms_off_is_refused_by_the_fit_and_named() -> None:
    config = load_config(ROOT / "config" / "sim.toml")
    twin = config.sim
    true_s = twin.laser.storage_latency_s + twin.robot.path_lag_s - twin.robot.feedback_latency_s
    off = with_align_mode(config, "on_the_fly", fixed_latency_s=true_s + OFF_S)
    run = run_accuracy(off, RunSettings(trials=1, seed=2, calibration="oracle", devices="twin"), progress=False)
    (trial,) = run.trials  # this cell's first cycle (seed 2): the passes up and down the side 0.26 mm apart in RMS
    assert trial.outcome == "failed" and trial.reason is not None, trial
    assert "wall fit RMS" in trial.reason and "exceeds the limit 0.2 mm" in trial.reason, trial.reason
    assert f"the laser's latency is off by milliseconds (this sweep paired its readings at {1e3 * (true_s + OFF_S):.2f} ms, fixed" in trial.reason
    right = with_align_mode(config, "on_the_fly", fixed_latency_s=true_s)  # the same cycle at the twin's latency installs
    assert run_accuracy(right, RunSettings(trials=1, seed=2, calibration="oracle", devices="twin"), progress=False).trials[0].outcome == "done"
