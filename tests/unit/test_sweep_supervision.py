"""The feedback supervision of a sweep (cellctl.cell.sweep): a stream that stops is a stopped robot and
alarm 1402; a host that stalls between reading the clock and the stream's newest sample is not."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import pytest

from cellctl.cell.cycle_failure import CycleFailed
from cellctl.cell.sweep import _supervised
from cellctl.domain import AlarmCode, CycleStep
from cellctl.ports import CartesianPose, PoseSample

STALE_S = 0.05
POSE = CartesianPose((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))


class CellClock:
    """The cell's clock, moved on by hand."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class Robot:
    def __init__(self) -> None:
        self.stopped = 0

    async def stop(self, *, timeout_s: float) -> None:
        self.stopped += 1


def cell_run(clock: CellClock, robot: Robot) -> SimpleNamespace:
    sweep = SimpleNamespace(feedback_stale_s=STALE_S)
    return SimpleNamespace(
        process=SimpleNamespace(align=SimpleNamespace(sweep=sweep)),
        dev=SimpleNamespace(clock=clock, robot=robot),
        motion=SimpleNamespace(read_timeout_s=1.0),
    )


class StallAfterEachSample:
    """Every sample is fresh when read; then the host stalls 0.1 s (the process was preempted)."""

    def __init__(self, clock: CellClock) -> None:
        self.clock = clock

    def latest(self) -> PoseSample:
        sample = PoseSample(self.clock.t, POSE)
        self.clock.t += 0.1
        return sample


class StopsAfter:
    """Samples every 4 ms until ``stop_at`` on the cell's clock, then none."""

    def __init__(self, clock: CellClock, stop_at: float) -> None:
        self.clock, self.stop_at = clock, stop_at

    def latest(self) -> PoseSample:
        self.clock.t += 0.004
        return PoseSample(min(self.clock.t, self.stop_at), POSE)

    async def stop_stream(self, *, timeout_s: float) -> tuple[PoseSample, ...]:
        return ()  # ended without a word: the sweep says only that the feedback stopped


async def test_a_stall_of_the_host_is_not_a_lost_stream() -> None:
    clock, robot = CellClock(), Robot()
    await _supervised(cell_run(clock, robot), CycleStep.ALIGN, asyncio.sleep(0.05), StallAfterEachSample(clock))  # type: ignore[arg-type]
    assert robot.stopped == 0
    assert clock.t > 100.5  # the supervision looked many times, each followed by a 0.1 s stall


async def test_a_stream_that_stops_stops_the_robot_with_alarm_1402() -> None:
    clock, robot = CellClock(), Robot()
    never = asyncio.Event()
    with pytest.raises(CycleFailed) as failed:
        await _supervised(cell_run(clock, robot), CycleStep.ALIGN, never.wait(), StopsAfter(clock, 100.2))  # type: ignore[arg-type]
    assert failed.value.code is AlarmCode.POSITION_FEEDBACK_LOST and robot.stopped == 1
    assert 100.2 + STALE_S < clock.t < 100.2 + STALE_S + 0.01  # stopped at the first look past the limit
