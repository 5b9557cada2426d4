"""robot_clear's bookkeeping (cellctl.plc.clearance): a reading counts only if no cycle ran since it began."""

from __future__ import annotations

import math

import pytest

from cellctl.plc.clearance import ClearanceWatch, FittedWall, flange_to_wall_mm


def test_the_distance_is_taken_along_the_walls_normal() -> None:
    n = (math.cos(0.1), math.sin(0.1), 0.0)  # into the wall
    wall = FittedWall(n, 1700.0)
    p = [1700.0 * n[0] - 389.0 * n[0] + 50.0 * -n[1], 1700.0 * n[1] - 389.0 * n[1] + 50.0 * n[0], 123.0]
    assert flange_to_wall_mm(p, wall) == pytest.approx(389.0)  # sideways and height do not count
    assert FittedWall.from_record({"normal": list(n), "offset_mm": 1700.0}) == wall
    assert FittedWall.from_record({"normal": [1.0, 1.0, 0.0], "offset_mm": 1.0}) is None  # not a unit normal
    assert FittedWall.from_record(None) is None


def test_a_cycle_running_voids_a_reading_begun_before_it_and_readings_expire() -> None:
    watch = ClearanceWatch(350.0, max_age_s=1.0)
    token = watch.begin()
    watch.settle(token, 10.0, 389.0)
    assert watch.clear(10.5) and not watch.clear(11.5)  # too old: the robot's link may be down
    token = watch.begin()
    watch.cycle_running()  # a cycle started while the pose was being read
    watch.settle(token, 20.0, 389.0)
    assert not watch.clear(20.1)
    watch.settle(watch.begin(), 21.0, 349.9)
    assert not watch.clear(21.1)
    watch.settle(watch.begin(), 22.0, None)  # the wall or the pose not known
    assert not watch.clear(22.1)
    with pytest.raises(ValueError, match="clear_distance_mm"):
        ClearanceWatch(0.0, 1.0)
