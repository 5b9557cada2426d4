"""A laser whose storage start the host notices late, on the twin: the flush sweep's latency against the truth.

The twin's laser is made to stamp each storage's start ``delay`` after the controller truly started it (the
host noticed the AS echo late) and to give the window that start lies in, as the LK-G driver does: the AS write
(0.1 ms before the start) to the echo noticed. Reading k then reflects the flange ``L0 + delay`` before its
stamped instant, ``L0`` being the twin's own latency. The flush sweep pairs with the alignment sweep's latency
moved to its own start, and a checking alignment sweep with the kept latency moved from the timing sweep's start
to its own: each must lie within the bound it gives of ``L0 + delay`` of its own storage.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import cellctl.cell.sweep as sweep_module
from cellctl.bench.accuracy import RunSettings, run_accuracy
from cellctl.bench.cycle_time import with_align_mode
from cellctl.config import load_config
from cellctl.domain import CycleStep
from cellctl.ports import StoredReadings
from cellctl.sim.devices import SimDisplacementSensor

ROOT = Path(__file__).resolve().parents[2]
WRITTEN_BEFORE_S = 0.0001  # the AS command's write before the controller starts


def late_notices(monkeypatch: pytest.MonkeyPatch, delays_s: list[float]) -> list[float]:
    """Each storage start is noticed the next of ``delays_s`` late (the last repeats); returns the delays used, in order."""
    used: list[float] = []
    start, stop = SimDisplacementSensor.start_storage, SimDisplacementSensor.stop_storage

    async def start_storage(self: Any, *, cycle_s: float, count: int, timeout_s: float) -> float:
        true_start = await start(self, cycle_s=cycle_s, count=count, timeout_s=timeout_s)
        delay = delays_s[min(len(used), len(delays_s) - 1)]
        used.append(delay)
        self.stamp_s = true_start + delay
        self.window_s = (true_start - WRITTEN_BEFORE_S, true_start + delay)
        return self.stamp_s

    async def stop_storage(self: Any, *, timeout_s: float) -> StoredReadings:
        stored = await stop(self, timeout_s=timeout_s)
        return StoredReadings(self.stamp_s, stored.cycle_s, stored.distances_mm)

    def storage_start_window(self: Any) -> tuple[float, float]:
        return self.window_s

    monkeypatch.setattr(SimDisplacementSensor, "start_storage", start_storage)
    monkeypatch.setattr(SimDisplacementSensor, "stop_storage", stop_storage)
    monkeypatch.setattr(SimDisplacementSensor, "storage_start_window", storage_start_window, raising=False)
    return used


def test_a_storage_start_noticed_late_is_started_again_and_the_flush_sweep_pairs_within_its_bound_of_the_truth(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # cycle 1: the timing sweep's first start noticed 20 ms late (started again), then 0.8 ms; its flush 0.1 ms.
    # cycle 2: the check's start noticed at once (it agrees with the kept latency within 1 ms, so it pairs with the
    # kept one moved to its own start: 0.4 ms off, not the 0.8 ms unmoved), its flush 0.1 ms late: the flush must
    # take the check's own latency, not the kept one.
    used = late_notices(monkeypatch, [0.020, 0.0008, 0.0001, 0.0, 0.0001])
    sweeps: list[tuple[CycleStep, Any]] = []
    inner = sweep_module.sweep_path

    async def spy(run: Any, step: CycleStep, corners: list[Any], **kw: Any) -> Any:
        swept = await inner(run, step, corners, **kw)
        sweeps.append((step, swept))
        return swept

    monkeypatch.setattr(sweep_module, "sweep_path", spy)
    config = with_align_mode(load_config(ROOT / "config" / "sim.toml"), "on_the_fly")
    twin = config.sim
    l0_s = twin.laser.storage_latency_s + twin.robot.path_lag_s - twin.robot.feedback_latency_s
    run = run_accuracy(config, RunSettings(trials=2, seed=2, calibration="oracle", devices="twin"), progress=False, workdir=tmp_path)
    assert [t.outcome for t in run.trials] == ["done", "done"], [t.reason for t in run.trials]
    assert used == [0.020, 0.0008, 0.0001, 0.0, 0.0001]  # the start noticed 20 ms late was started again
    assert [step for step, _ in sweeps] == [CycleStep.ALIGN, CycleStep.INSPECT] * 2
    assert sweeps[0][1].start.restarts == 1 and sweeps[0][1].start.width_s < 0.001
    check, timing = sweeps[2][1], sweeps[0][1]  # the check agreed: it paired with the kept latency, not its own
    assert check.latency_s != check.estimate.latency_s
    # ... moved from the timing sweep's start (noticed 0.8 ms late) to its own (at once): within the two windows'
    # halves (0.45 + 0.05 ms) of its truth, where the kept latency as timed would be 0.8 ms off
    bound_s = 0.5 * (timing.start.width_s + check.start.width_s)
    assert abs(bound_s - 0.0005) < 1e-6, bound_s
    assert abs(check.latency_s - l0_s) <= bound_s + 0.00025, (1e3 * check.latency_s, 1e3 * l0_s)
    assert abs(timing.latency_s - l0_s) > 0.0007 and abs(check.latency_s - l0_s) < abs(timing.latency_s - l0_s) - 0.0003
    for k, delay in ((1, 0.0001), (3, 0.0001)):  # the flush sweeps
        swept = sweeps[k][1]
        truth_s = l0_s + delay
        bound_s = 1e-3 * swept.figures["latency_bound_ms"]
        # the bound holds the windows; the alignment sweep's estimate adds its own error (a check on one move in: about
        # 0.1 ms on the twin), well below the 0.8 ms the kept latency would be off here
        assert abs(swept.latency_s - truth_s) <= bound_s + 0.00025, (k, 1e3 * swept.latency_s, 1e3 * truth_s, 1e3 * bound_s)


def test_a_check_searches_near_the_kept_latency_moved_to_its_own_storage_start(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # cycle 1: every start of the timing sweep noticed 8 ms late (its restarts run out: timed from an 8 ms wide window);
    # cycle 2: the check's start noticed at once. The kept latency as timed lies 8 ms past the check's truth, outside
    # the check's +-5 ms search; moved to the check's start it lies within the windows' halves (about 4 ms) of it.
    # No inspection: its flush sweep would refuse to move a latency known within 8 ms, and a failed cycle times anew.
    used = late_notices(monkeypatch, [0.008, 0.008, 0.008, 0.008, 0.0])
    centres: list[float | None] = []
    inner = sweep_module._latency

    def spy(*args: Any) -> Any:
        centres.append(args[-1])  # check_s: where a check searches first
        return inner(*args)

    monkeypatch.setattr(sweep_module, "_latency", spy)
    config = with_align_mode(load_config(ROOT / "config" / "sim.toml"), "on_the_fly")
    process = config.process.model_copy(update={"inspect": config.process.inspect.model_copy(update={"enabled": False})})
    config = config.model_copy(update={"process": process})
    twin = config.sim
    l0_s = twin.laser.storage_latency_s + twin.robot.path_lag_s - twin.robot.feedback_latency_s
    run = run_accuracy(config, RunSettings(trials=2, seed=2, calibration="oracle", devices="twin"), progress=False, workdir=tmp_path)
    assert [t.outcome for t in run.trials] == ["done", "done"], [t.reason for t in run.trials]
    assert used == [0.008] * 4 + [0.0], used
    assert centres[0] is None and len(centres) == 2, centres  # the timing sweep, then the check
    assert centres[1] is not None and abs(centres[1] - l0_s) < sweep_module.CHECK_WINDOW_S - 0.0005, (1e3 * centres[1], 1e3 * l0_s)
