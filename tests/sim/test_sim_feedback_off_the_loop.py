"""The twin's feedback and the sweep's pose arrays are built off the event loop (a sweep's thousands of samples
held the loop for 0.3-0.9 s: the REST API, the PLC scan and the heartbeat stood meanwhile).

Structural, not timed: a spy on the per-sample work notes whether an event loop runs in the thread it is called on.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import cellctl.cell.sweep as sweep_module
from cellctl.bench.accuracy import RunSettings, run_accuracy
from cellctl.bench.cycle_time import with_align_mode
from cellctl.config import load_config
from cellctl.config.sim import SimConfig
from cellctl.ports import CartesianPose, MotionRequest
from cellctl.sim.cell import SimCell
from cellctl.sim.devices import SimRobot

pytestmark = pytest.mark.timeout(120)
ROOT = Path(__file__).resolve().parents[2]


def _on_a_loop() -> bool:
    try:
        asyncio.get_running_loop()
    except RuntimeError:
        return False
    return True


async def test_stop_stream_builds_the_samples_in_a_worker_thread() -> None:
    cell = SimCell(SimConfig.model_validate({"seed": 6, "time_scale": 0.001}))
    robot = SimRobot(cell)
    start = CartesianPose.from_matrix(cell.arm.belief_pose())
    x, y, z = start.position_mm
    await robot.start_stream(timeout_s=5.0)
    await robot.move(MotionRequest(CartesianPose((x + 200.0, y, z), start.quaternion_wxyz), speed_mm_s=250.0), timeout_s=5.0)
    calls: list[bool] = []
    real = cell.arm.belief_at_line

    def spy(t: float) -> Any:
        calls.append(_on_a_loop())
        return real(t)

    cell.arm.belief_at_line = spy  # type: ignore[method-assign]
    samples = await robot.stop_stream(timeout_s=5.0)
    assert len(samples) > 100 and len(calls) >= len(samples)  # one pose per sample, built during the call
    assert not any(calls), f"{sum(calls)} of {len(calls)} feedback poses were built on the event loop"
    xs = np.array([s.pose.position_mm[0] for s in samples])
    assert xs[-1] - xs[0] == pytest.approx(200.0, abs=1.0)  # the samples are the move's path, as before


def test_an_on_the_fly_cycle_builds_its_feedback_arrays_off_the_loop(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: dict[str, list[bool]] = {"feedback": [], "arrays": []}
    feedback, arrays = SimRobot._feedback, sweep_module.pose_samples_arrays

    def feedback_spy(self: SimRobot, t_from: float, t_to: float) -> Any:
        seen["feedback"].append(_on_a_loop())
        return feedback(self, t_from, t_to)

    def arrays_spy(samples: Any) -> Any:
        seen["arrays"].append(_on_a_loop())
        return arrays(samples)

    monkeypatch.setattr(SimRobot, "_feedback", feedback_spy)
    monkeypatch.setattr(sweep_module, "pose_samples_arrays", arrays_spy)
    config = with_align_mode(load_config(ROOT / "config" / "sim.toml"), "on_the_fly")
    run = run_accuracy(config, RunSettings(trials=1, seed=2, calibration="oracle", devices="twin"), progress=False)
    assert run.trials[0].outcome == "done", run.trials[0]
    assert seen["feedback"] and seen["arrays"], seen  # the cycle swept (the spies were called)
    assert not any(seen["feedback"]), "SimRobot.stop_stream built its feedback samples on the event loop"
    assert not any(seen["arrays"]), "the sweep built its pose arrays (pose_samples_arrays) on the event loop"
