"""The storage start window (cellctl.cell.sweep_start) against a start known here: a controller that truly starts
at ``true_start_s`` inside the window, a host that stamps it later, and a device latency ``DEVICE_S`` referred to
the true start. A sweep's latency referred to its stamp is then ``DEVICE_S + (stamp - true start)``; the flush
sweep's latency moved from the alignment sweep's must come within the bound it gives of its own true one.
"""

from __future__ import annotations

import itertools

import pytest

from cellctl.cell.cycle_failure import CycleFailed
from cellctl.cell.sweep import _moved_latency
from cellctl.cell.sweep_start import RESTARTS, StartWindow, SweepLatency, start_known
from cellctl.domain import AlarmCode, CycleStep
from cellctl.ports import StoredReadings

DEVICE_S = 0.0073  # the laser's and the robot's own latency, referred to the storage's true start


def latency_at_stamp(stamp_s: float, true_start_s: float) -> float:
    """The latency a sweep finds referred to its stamp: readings are stamped ``stamp - true start`` late."""
    return DEVICE_S + (stamp_s - true_start_s)


def aligned(window: tuple[float, float], stamp_s: float, true_start_s: float) -> SweepLatency:
    """The alignment sweep's own latency, timed against a storage that truly started at ``true_start_s``."""
    est = latency_at_stamp(stamp_s, true_start_s)
    return SweepLatency(est, 2e-5, "timed", StartWindow(stamp_s, *window), est)


def test_the_latency_moved_to_the_flush_sweeps_start_is_its_own_when_both_starts_lie_mid_window() -> None:
    # alignment: AS written at 10.000 s, echo noticed at 10.020 s (a loaded host), the controller started at 10.010
    # flush: AS written at 20.000 s, echo noticed at 20.002 s, the controller started at 20.001
    ref = aligned((10.000, 10.020), 10.020, 10.010)
    moved, bound = ref.moved_to(StartWindow(20.002, 20.000, 20.002))
    assert moved == pytest.approx(latency_at_stamp(20.002, 20.001), abs=1e-9)  # 8.3 ms: the stamp is 1 ms late here
    assert bound == pytest.approx(0.011, abs=1e-9)  # half of each window


def test_the_moved_latency_is_never_further_from_the_truth_than_the_bound_it_gives() -> None:
    windows = ((10.000, 10.020), (20.000, 20.002))
    stamps = (10.020, 20.002)
    worst = 0.0
    # the controllers' true starts anywhere in their windows, the edges included (there the bound is reached)
    for a, b in itertools.product((10.000, 10.005, 10.010, 10.020), (20.000, 20.001, 20.002)):
        ref = aligned(windows[0], stamps[0], a)
        moved, bound = ref.moved_to(StartWindow(stamps[1], *windows[1]))
        off = abs(moved - latency_at_stamp(stamps[1], b))
        assert off <= bound + 1e-9, (a, b, off, bound)
        worst = max(worst, off)
    assert worst == pytest.approx(0.011, abs=1e-9)  # the bound is tight: half of both windows together


def test_a_flush_sweep_whose_laser_gives_no_window_takes_the_latency_at_the_alignments_window_middle() -> None:
    # the flush sweep's stamp taken as exact (its driver gives no window): its true latency is the device's own
    ref = aligned((10.000, 10.020), 10.020, 10.010)
    moved, bound = ref.moved_to(None)
    assert moved == pytest.approx(DEVICE_S, abs=1e-9) and bound == pytest.approx(0.010, abs=1e-9)
    exact = SweepLatency(DEVICE_S, 2e-5, "timed", None, DEVICE_S)  # neither gives one: nothing to move
    assert exact.moved_to(None) == (DEVICE_S, 0.0)


def test_a_flush_sweep_whose_latency_may_be_off_beyond_the_tolerance_is_refused_before_it_measures() -> None:
    ref = aligned((10.000, 10.020), 10.020, 10.010)
    with pytest.raises(CycleFailed) as failed:
        _moved_latency(CycleStep.INSPECT, ref, StartWindow(20.002, 20.000, 20.002), 0.001)
    assert failed.value.code is AlarmCode.INSPECTION_FAILED and "11.00 ms off" in failed.value.reason
    tight = aligned((10.000, 10.0006), 10.0006, 10.0003)
    latency_s, figures = _moved_latency(CycleStep.INSPECT, tight, StartWindow(20.0004, 20.000, 20.0004), 0.001)
    assert latency_s == pytest.approx(latency_at_stamp(20.0004, 20.0002), abs=1e-9)
    assert figures["latency_bound_ms"] == pytest.approx(0.5, abs=1e-6)


class WindowedLaser:
    """A laser whose successive storage starts are known within the given windows (s); refuses a 10th start."""

    def __init__(self, widths_s: list[float]) -> None:
        self.widths_s, self.starts, self.t = widths_s, 0, 100.0

    async def start_storage(self, *, cycle_s: float, count: int, timeout_s: float) -> float:
        if self.starts >= 10:
            raise RuntimeError("started ten times: a start that is never known stops the sweep")
        self.width = self.widths_s[min(self.starts, len(self.widths_s) - 1)]
        self.starts += 1
        self.t += 1.0
        return self.t + self.width

    def storage_start_window(self) -> tuple[float, float]:
        return self.t, self.t + self.width

    async def stop_storage(self, *, timeout_s: float) -> StoredReadings:
        return StoredReadings(self.t, 0.01, ())


async def test_a_storage_whose_start_is_not_known_within_the_tolerance_starts_again() -> None:
    laser = WindowedLaser([0.020, 0.004, 0.0005])  # a loaded host twice, then a prompt one
    window = await start_known(laser, cycle_s=0.01, count=100, timeout_s=1.0, within_s=0.001)  # type: ignore[arg-type]
    assert laser.starts == 3 and window is not None
    assert window.width_s == pytest.approx(0.0005) and window.restarts == 2


async def test_a_start_never_known_within_the_tolerance_gives_up_after_the_restarts_allowed() -> None:
    laser = WindowedLaser([0.020])
    window = await start_known(laser, cycle_s=0.01, count=100, timeout_s=1.0, within_s=0.001)  # type: ignore[arg-type]
    assert laser.starts == 1 + RESTARTS and window is not None and window.restarts == RESTARTS
    assert window.width_s == pytest.approx(0.020)  # the sweep's own tolerance check refuses it later
