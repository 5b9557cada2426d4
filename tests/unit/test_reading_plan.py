"""The predicted plane error of a choice of wall readings, against closed forms and brute force."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from cellctl.align.reading_plan import fastest_order, predicted_plane_error, standing_readings, sweep_readings

SPOTS = [(-1500.0, -60.0), (-500.0, -60.0), (60.0, 300.0), (60.0, 1200.0), (-1000.0, 1560.0), (-2060.0, 750.0)]


def test_standing_spots_match_the_least_squares_closed_form() -> None:
    # independent errors sigma per spot: the offset's sigma is sigma * sqrt((A^T A)^-1)[0, 0]
    xy = np.array(SPOTS)
    A = np.column_stack([np.ones(len(xy)), xy])
    expected = 0.05 * np.sqrt(np.linalg.inv(A.T @ A)[0, 0])
    _, offset = predicted_plane_error(standing_readings(SPOTS), laser_sigma_mm=0.0, robot_sigma_mm=0.05, draws=20000)
    assert offset == pytest.approx(expected, rel=0.03)


def test_a_sweep_gains_nothing_over_its_stops_when_the_robot_error_dominates() -> None:
    corners = [(-1500.0, -60.0), (60.0, -60.0), (60.0, 1200.0)]
    sweep = sweep_readings(corners, 2.0)
    assert len(sweep.xy_mm) > 1000 and sweep.n_stops == 3
    kw = {"laser_sigma_mm": 0.0, "robot_sigma_mm": 0.05, "draws": 4000}
    many = predicted_plane_error(sweep, **kw)
    three = predicted_plane_error(standing_readings(corners), **kw)
    # the readings between the corners blend the corners' errors: the plane is the corners' plane
    assert many[1] == pytest.approx(three[1], rel=0.05) and many[0] == pytest.approx(three[0], rel=0.05)
    # ... while against the laser's noise alone the many readings do beat three
    quiet = {"laser_sigma_mm": 0.002, "robot_sigma_mm": 0.0, "draws": 2000}
    assert predicted_plane_error(sweep, **quiet)[1] < 0.2 * predicted_plane_error(standing_readings(corners), **quiet)[1]


def test_readings_on_a_line_are_refused() -> None:
    with pytest.raises(ValueError, match="on a line"):
        predicted_plane_error(standing_readings([(0.0, 0.0), (100.0, 0.0), (300.0, 0.0)]), laser_sigma_mm=0.002,
                              robot_sigma_mm=0.05)  # fmt: skip


def test_the_fastest_order_is_the_best_of_every_order() -> None:
    rng = np.random.default_rng(3)
    pts = rng.uniform(0.0, 1000.0, (6, 2))

    def cost(i: int, j: int) -> float:
        return float(np.linalg.norm(pts[i] - pts[j]))

    order, total = fastest_order(len(pts), cost)
    brute = min(sum(cost(a, b) for a, b in itertools.pairwise(p)) for p in itertools.permutations(range(6)))
    assert total == pytest.approx(brute) and sorted(order) == list(range(6))
    line = [5.0, 1.0, 3.0, 2.0, 4.0]
    order, _ = fastest_order(5, lambda i, j: abs(line[i] - line[j]), first=1)
    assert order == [1, 3, 2, 4, 0]  # along the line from the given first stop


def test_the_default_sweep_comes_back_to_the_cameras_corner_and_steadies_the_plane_there_as_the_spots_do() -> None:
    # The sweep's plane at the window's corner rests on the robot's draws at the stops nearest it; the default
    # path stands twice at the corner beside the window's (out and back), so the offset there is no worse than
    # the six standing spots'. A path that stands there once (the old default) is worse than both.
    from cellctl.config.cell import AlignConfig

    align = AlignConfig()
    kw = {"laser_sigma_mm": 0.002, "robot_sigma_mm": 0.0277, "draws": 20000}
    spots = predicted_plane_error(standing_readings(align.spots_mm), **kw)[1]
    path = np.asarray(align.sweep.path_mm)
    near = np.linalg.norm(path, axis=1) < 100.0
    assert np.count_nonzero(near) == 2 and near[-1]  # the path ends beside the corner the camera shoots
    sweep = predicted_plane_error(sweep_readings(path, 10.0), **kw)[1]
    once = predicted_plane_error(sweep_readings(path[:-1], 10.0), **kw)[1]
    assert sweep <= spots < once
