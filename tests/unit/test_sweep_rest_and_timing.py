"""Reading on the move (issue 19): the latency kept between sweeps, the stops found in the feedback, and the
wall's offset taken at rest (the arm's deviation at speed moves a moving flange off its reported path)."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from cellctl.align import AlignmentError, compute_alignment
from cellctl.align.laser_points import sweep_route
from cellctl.align.onthefly import LatencyEstimate, at_corners, even_along_path, standing
from cellctl.cell.laser_timing import LaserTiming
from cellctl.config.cell import AlignConfig
from cellctl.geometry.pose import make_pose


def _estimate(latency_s: float, sigma_s: float = 2e-5) -> LatencyEstimate:
    return LatencyEstimate(latency_s, sigma_s, 0.003, 500, 40.0, np.array([1.0, 0.0, 0.0]), 2000.0)


def test_the_latency_is_timed_first_then_checked_until_it_is_due_again() -> None:
    timing, laser, robot = LaserTiming(), object(), object()
    assert "first sweep" in (timing.why_time(laser, robot, 3) or "")
    timing.timed(_estimate(0.0073), laser, robot)
    for _ in range(2):
        assert timing.why_time(laser, robot, 3) is None
        used, figures = timing.checked(_estimate(0.0075), 0.001)
        assert used == 0.0073 and figures["agrees"] is True  # the timed value stays: three moves beat one
    assert "3 sweeps" in (timing.why_time(laser, robot, 3) or "")
    assert "another device" in (timing.why_time(object(), robot, 3) or "")  # a swapped laser is timed anew


class _Driver:
    pass


def test_a_driver_replaced_after_the_old_one_is_gone_is_timed_anew() -> None:
    timing, robot = LaserTiming(), object()
    timing.timed(_estimate(0.0073), _Driver(), robot)  # the caller keeps no reference to the timed laser's driver
    for _ in range(20):  # CPython hands a freed object's address (its id()) to the next one of its size
        assert "another device" in (timing.why_time(_Driver(), robot, 25) or "")


def test_a_check_that_disagrees_is_used_once_and_the_next_sweep_times_anew() -> None:
    timing, laser, robot = LaserTiming(), object(), object()
    timing.timed(_estimate(0.0073), laser, robot)
    used, figures = timing.checked(_estimate(0.0121), 0.001)
    assert used == 0.0121 and figures["agrees"] is False and figures["off_ms"] == pytest.approx(4.8)
    assert "12.10 ms against the kept 7.30 ms" in (timing.why_time(laser, robot, 25) or "")
    timing.timed(_estimate(0.0120), laser, robot)
    assert timing.why_time(laser, robot, 25) is None


def test_a_failed_cycle_makes_the_next_sweep_time_anew() -> None:
    timing, laser, robot = LaserTiming(), object(), object()
    timing.forget("cycle 3 failed")  # nothing kept yet: still the first sweep's reason
    assert "first sweep" in (timing.why_time(laser, robot, 25) or "")
    timing.timed(_estimate(0.0073), laser, robot)
    timing.forget("cycle 4 failed")
    assert timing.why_time(laser, robot, 25) == "cycle 4 failed"


def test_the_route_moves_along_the_beam_three_times_to_time_once_to_check_and_not_at_all_when_known() -> None:
    corners = [make_pose(np.eye(3), [0.0, y, 0.0]) for y in (0.0, 1000.0, 1500.0)]
    l = np.array([0.0, 0.0, 1.0])  # noqa: E741
    z = {n: [float(T[2, 3]) for T in sweep_route(corners, l, 40.0, beam_moves=n)] for n in (0, 1, 3)}
    assert z == {0: [0.0, 0.0, 0.0], 1: [-40.0, 0.0, 0.0, 0.0], 3: [-40.0, 0.0, -40.0, 0.0, 0.0, 0.0]}
    with pytest.raises(ValueError, match="beam_moves"):
        sweep_route(corners, l, 40.0, beam_moves=2)


def test_standing_finds_the_stops_in_the_feedback() -> None:
    t = np.arange(0.0, 1.0, 0.004)
    x = np.clip((t - 0.2) * 1000.0, 0.0, 400.0)  # stands until 0.2 s, moves at 1000 mm/s, stands from 0.6 s
    T = np.tile(np.eye(4), (t.size, 1, 1))
    T[:, 0, 3] = x
    q = np.array([0.1, 0.21, 0.4, 0.61, 0.62, 0.7, 0.95])
    # 0.61 and 0.62 s: the flange stopped less than hold_s ago (its arm may still trail the reported path)
    assert standing(t, T, q, hold_s=0.03).tolist() == [True, False, False, False, False, True, True]
    assert standing(t, T, [0.01], hold_s=0.03).tolist() == [False]  # before the feedback began: not known to stand


def _sweep(offsets_mm: tuple[float, float], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Flange poses along an L in front of the wall x = 1000 mm (beam along +x) and the distances read: on
    leg k the flange truly stands ``offsets_mm[k]`` nearer the wall than reported (a deviation at speed)."""
    ys = np.r_[np.linspace(-800.0, 0.0, 80), np.zeros(60)]
    zs = np.r_[np.zeros(80), np.linspace(0.0, 600.0, 60)]
    legs = np.r_[np.zeros(80, dtype=int), np.ones(60, dtype=int)]
    poses = np.array([make_pose(np.eye(3), [600.0, y, z]) for y, z in zip(ys, zs)])
    return poses, 400.0 - np.take(offsets_mm, legs) + rng.normal(0.0, 0.002, ys.size)


def test_the_offset_comes_from_the_stops_and_the_normal_from_all_readings() -> None:
    rng = np.random.default_rng(4)
    r, l = np.zeros(3), np.array([1.0, 0.0, 0.0])  # noqa: E741
    moving, d_moving = _sweep((0.1, 0.1), rng)  # as at 1000 mm/s: the moving flange 0.1 mm nearer than reported
    stops, d_stops = _sweep((0.0, 0.0), rng)
    rest, d_rest = stops[[0, 79, 139]].repeat(10, axis=0), d_stops[[0, 79, 139]].repeat(10)  # three stops
    plain = compute_alignment(moving, d_moving, r, l, np.eye(4), 400.0)
    rested = compute_alignment(moving, d_moving, r, l, np.eye(4), 400.0, at_rest=(rest, d_rest))
    assert plain.wall.offset == pytest.approx(999.9, abs=0.005)  # the legs alone: the deviation passes into D
    assert rested.wall.offset == pytest.approx(1000.0, abs=0.005) and rested.wall.rest_shift_mm == pytest.approx(0.1, abs=0.005)
    assert np.allclose(rested.wall.normal, plain.wall.normal)
    assert rested.distance.delta_d_mm - plain.distance.delta_d_mm == pytest.approx(0.1, abs=0.005)
    assert plain.wall.rest_shift_mm is None


def test_too_few_readings_at_rest_are_refused_with_the_reason() -> None:
    rng = np.random.default_rng(5)
    r, l = np.zeros(3), np.array([1.0, 0.0, 0.0])  # noqa: E741
    poses, d = _sweep((0.0, 0.0), rng)
    with pytest.raises(AlignmentError, match="stand still at its corners"):
        compute_alignment(poses, d, r, l, np.eye(4), 400.0, at_rest=(poses[:4], d[:4]))


def test_each_stop_weighs_the_same_in_the_offset_however_long_the_flange_stood_there() -> None:
    # The robot's accuracy puts the wall 0.03 mm nearer at one corner and 0.03 mm farther at the other; the sweep
    # stood at the first five times as long (it timed the laser there). Teaching reads each corner once.
    rng = np.random.default_rng(6)
    r, l = np.zeros(3), np.array([1.0, 0.0, 0.0])  # noqa: E741
    poses, d = _sweep((0.0, 0.0), rng)
    rest = np.r_[poses[[0] * 50], poses[[139] * 10]]
    d_rest = np.r_[np.full(50, 400.0 - 0.03), np.full(10, 400.0 + 0.03)]
    stops = np.r_[np.zeros(50, dtype=int), np.ones(10, dtype=int)]
    pooled = compute_alignment(poses, d, r, l, np.eye(4), 400.0, at_rest=(rest, d_rest))
    by_stop = compute_alignment(poses, d, r, l, np.eye(4), 400.0, at_rest=(rest, d_rest, stops))
    assert pooled.wall.offset == pytest.approx(1000.0 - 0.02, abs=0.002)  # the long stop outweighs the short
    assert by_stop.wall.offset == pytest.approx(1000.0, abs=0.002)
    once = compute_alignment(poses, d, r, l, np.eye(4), 400.0, at_rest=(rest[[0, 50]], d_rest[[0, 50]], [0, 1]), min_rest_points=2)
    assert once.wall.offset == pytest.approx(by_stop.wall.offset, abs=1e-9)  # one reading a stop: the same offset


def test_the_fitted_readings_spread_evenly_along_the_path_not_in_time() -> None:
    # One reading a storage cycle while the arm ramps up from a corner, cruises and stands at the next corner.
    t = np.arange(0.0, 2.0, 0.01)
    x = np.where(t < 0.5, 1000.0 * t**2, np.minimum(250.0 + 1000.0 * (t - 0.5), 1250.0))
    poses = np.tile(np.eye(4), (t.size, 1, 1))
    poses[:, 0, 3] = x
    keep = even_along_path(poses, 50)
    gaps = np.diff(x[keep])
    assert 45 <= keep.size <= 50 and gaps.max() < 2.0 * 1250.0 / 49  # no stretch of the path left out
    assert np.count_nonzero(x[keep] >= 1249.9) <= 1  # the standing readings count once, not for every cycle
    assert np.array_equal(even_along_path(poses[:40], 50), np.arange(40))  # fewer than asked: all of them


def test_the_readings_at_rest_count_at_the_corner_they_were_read_at_and_not_out_along_the_beam() -> None:
    corners = [make_pose(np.eye(3), [0.0, y, 0.0]) for y in (0.0, 1000.0, 1500.0)]
    back = make_pose(np.eye(3), [-40.0, 0.0, 0.0])  # standing 40 mm out along the beam while timing the laser
    poses = np.array([back, corners[0], back, corners[1], corners[1], corners[2], make_pose(np.eye(3), [0.0, 500.0, 0.0])])
    poses[4, :3, 3] += [0.0, 0.5, 0.3]  # the reported pose at a stop: within a millimetre of the corner
    moving = np.array([False, False, False, False, False, False, True])
    idx, corner = at_corners(poses, ~moving, corners, 2.0)
    assert idx.tolist() == [1, 3, 4, 5] and corner.tolist() == [0, 1, 1, 2]


def test_a_path_that_comes_back_to_a_corner_counts_its_two_stops_there_apart() -> None:
    # corners 1 and 3 are one place: each stand is its own draw of the robot's error, told apart by when it was read
    corners = [make_pose(np.eye(3), [0.0, y, 0.0]) for y in (0.0, 1000.0, 1500.0, 1000.0)]
    poses = np.array([corners[0], corners[1], corners[2], corners[3], corners[3], corners[1]])
    stop_of = np.array([0, 1, 2, 3, 3, 2])  # the last: read while standing at corner 2's stop, though near corner 1
    idx, corner = at_corners(poses, np.ones(6, dtype=bool), corners, 2.0, stop_of=stop_of)
    assert idx.tolist() == [0, 1, 2, 3, 4] and corner.tolist() == [0, 1, 2, 3, 3]
    assert at_corners(poses, np.ones(6, dtype=bool), corners, 2.0)[1].tolist() == [0, 1, 2, 1, 1, 1]  # by place alone


def test_teaching_on_the_move_reads_the_paths_corners_as_its_stops() -> None:
    align = AlignConfig(mode="on_the_fly", sweep={"path_mm": [[-1500.0, -60.0], [60.0, -60.0], [60.0, 1200.0]]})
    spots, stops = align.wall_spots_mm(), align.wall_stops()
    assert [spots[k] for k in stops] == [(-1500.0, -60.0), (60.0, -60.0), (60.0, 1200.0)]
    assert max(np.hypot(*np.subtract(a, b)) for a, b in zip(spots, spots[1:])) <= 100.0
    assert AlignConfig().wall_stops() == ()  # stop and go: the plane's offset from all its spots


def test_a_path_with_a_leg_of_no_length_is_refused_naming_its_corners() -> None:
    with pytest.raises(ValidationError, match=r"path_mm corners 2 and 3 are the same point \[60.0, 1200.0\]: a leg needs a length"):
        AlignConfig(mode="on_the_fly", sweep={"path_mm": [[-1500.0, -60.0], [60.0, -60.0], [60.0, 1200.0], [60.0, 1200.0]]})
    AlignConfig(mode="on_the_fly", sweep={"path_mm": [[-1500.0, -60.0], [60.0, -60.0], [60.0, 1200.0], [60.0, -60.0]]})  # back: fine
