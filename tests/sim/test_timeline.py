"""The twin's time line: waits count in full, the twin's own computing does not (issue 19's cycle time)."""

from __future__ import annotations

import threading

import pytest

from cellctl.sim.timeline import TwinTimeline


class ManualClock:
    """A monotonic clock the test advances by hand."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_a_wait_counts_in_full_and_computing_at_its_real_duration() -> None:
    clock = ManualClock()
    line = TwinTimeline(0.001, clock)
    start = line.now()
    line.waited(2.0)  # a 2 s move, slept 2 ms
    clock.t += 0.002
    clock.t += 0.3  # the cell's own computing
    assert line.now() - start == pytest.approx(2.3)


def test_the_clock_stands_still_while_the_twin_computes_and_goes_on_after() -> None:
    clock = ManualClock()
    line = TwinTimeline(0.001, clock)
    before = line.now()
    with line.unclocked():
        clock.t += 0.8  # ray casts or a rendering
        assert line.now() == before
        line.waited(0.5)  # a wait begun meanwhile still counts
        assert line.now() == pytest.approx(before + 0.4995)
    assert line.now() == pytest.approx(before + 0.4995)
    clock.t += 0.1
    assert line.now() == pytest.approx(before + 0.5995)


def test_overlapping_blocks_stand_the_clock_still_once() -> None:
    clock = ManualClock()
    line = TwinTimeline(1.0, clock)
    before = line.now()
    outer = line.unclocked()
    outer.__enter__()
    clock.t += 0.2
    with line.unclocked():
        clock.t += 0.3
    assert line.now() == before  # the outer block still runs
    clock.t += 0.1
    outer.__exit__(None, None, None)
    assert line.now() == pytest.approx(before)
    clock.t += 0.05
    assert line.now() == pytest.approx(before + 0.05)


def test_the_clock_never_runs_backwards_across_threads() -> None:
    line = TwinTimeline(0.5)
    seen: list[float] = []
    stop = threading.Event()

    def watch() -> None:
        while not stop.is_set():
            seen.append(line.now())

    watcher = threading.Thread(target=watch)
    watcher.start()
    try:
        for _ in range(200):
            with line.unclocked():
                line.waited(0.001)
    finally:
        stop.set()
        watcher.join()
    assert all(b >= a for a, b in zip(seen, seen[1:]))
