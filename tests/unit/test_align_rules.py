"""The alignment's guards and its predicted wall-normal uncertainty, against truth: Monte Carlo draws of spots with a
known noise on a known wall. Each test fails when its rule is removed."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import scipy.optimize

import cellctl.align.orientation as orientation
from cellctl.align import (
    AlignmentError,
    correct_distance,
    fit_wall_plane,
    predict_normal_uncertainty,
    solve_orientation_lm,
    solve_orientation_minimal,
)
from cellctl.geometry import angle_between_vectors, make_pose, rot_y
from cellctl.geometry.plane import fit_plane

WALL_X = 1000.0
SENSOR = np.array([600.0, 0.0, 0.0])  # the sensor's side of the wall x = 1000
TRUE_NORMAL = np.array([1.0, 0.0, 0.0])  # into the wall


def _fits(spots_yz: np.ndarray, sigma_mm: float, draws: int, seed: int, *, known: bool = False) -> tuple[np.ndarray, list[Any]]:
    """``draws`` wall fits of spots (y, z) on the wall x = WALL_X, each read with normal noise ``sigma_mm`` along x:
    the angle of each fitted normal from the true one (rad), and each fit's predicted uncertainty (from its residuals,
    or with ``known`` from the true noise)."""
    rng = np.random.default_rng(seed)
    angles, predicted = [], []
    for _ in range(draws):
        x = WALL_X + rng.normal(0.0, sigma_mm, len(spots_yz))
        wall = fit_wall_plane(np.column_stack([x, spots_yz]), SENSOR, inlier_threshold_mm=10 * sigma_mm)
        angles.append(angle_between_vectors(wall.normal, TRUE_NORMAL))
        predicted.append(predict_normal_uncertainty(wall.plane, sigma_mm) if known else wall.uncertainty)
    return np.array(angles), predicted


def test_the_noise_estimated_from_the_residuals_is_unbiased() -> None:
    """A plane takes three of the spots' degrees of freedom: sum(r^2) / (n - 3) estimates the noise variance without
    bias (with / n, six spots would report half of it and the predicted normal error would be 0.7 of the truth)."""
    spots = np.array([[-1500.0, -60.0], [-500.0, -60.0], [60.0, 300.0], [60.0, 1200.0], [-1000.0, 1560.0], [-2060.0, 750.0]])
    sigma = 0.02
    angles, predicted = _fits(spots, sigma, draws=1500, seed=11)
    variance = np.mean([u.sigma_mm**2 for u in predicted])
    assert variance == pytest.approx(sigma**2, rel=0.08)
    # and the predicted rms normal error, from the layout and that noise, is the observed one
    assert np.sqrt(np.mean(angles**2)) == pytest.approx(np.sqrt(np.mean([u.rms_rad**2 for u in predicted])), rel=0.08)


def test_the_95_percent_cone_holds_the_true_normal_on_a_long_narrow_layout() -> None:
    """The cone takes the larger of the two tilt sigmas: on spots spread 2 m one way and 0.1 m the other, the tilt
    about the long axis is 20 times the other, and a cone sized by the smaller would miss the true normal most times."""
    spots = np.array([[-1000.0, 0.0], [-500.0, 100.0], [0.0, 0.0], [500.0, 100.0], [1000.0, 0.0], [1000.0, 100.0]])
    angles, predicted = _fits(spots, 0.05, draws=1000, seed=12, known=True)
    tilt = np.array([u.tilt_sigma_rad for u in predicted])
    assert np.median(tilt.max(axis=1) / tilt.min(axis=1)) > 10
    held = np.mean(angles <= np.array([u.cone95_rad for u in predicted]))
    assert 0.93 <= held <= 1.0


@pytest.mark.parametrize("working_distance_mm", [0.0, -400.0, float("nan"), float("inf")])
def test_a_working_distance_that_is_not_a_positive_number_is_refused(working_distance_mm: float) -> None:
    """Eq. 14 moves the camera to the working distance: none, a negative or a non-finite one is refused, not obeyed."""
    wall = fit_wall_plane(np.array([[WALL_X, 0, 0], [WALL_X, 500, 50], [WALL_X, 30, 480], [WALL_X, 520, 530.0]]), SENSOR)
    T = make_pose(rot_y(np.pi / 2), [WALL_X - 600.0, 200.0, 200.0])
    with pytest.raises(AlignmentError, match="working distance must be a positive number of mm"):
        correct_distance(T, make_pose(np.eye(3), [0.0, 0.0, 150.0]), wall.plane, working_distance_mm)


@pytest.mark.parametrize("solve", [solve_orientation_lm, solve_orientation_minimal])
def test_a_normal_that_is_not_a_unit_vector_is_refused(solve: Any) -> None:
    """Eq. 13 equates a rotated unit axis with the normal: a normal of another length has no solution, and the
    closed form would turn the camera by a wrong angle; both refuse it and name it."""
    with pytest.raises(AlignmentError, match="wall normal must be a finite unit 3-vector"):
        solve(np.eye(3), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.001]))
    with pytest.raises(AlignmentError, match="camera z axis in H must be a finite unit 3-vector"):
        solve(np.eye(3), np.array([0.0, 0.0, 1.01]), np.array([1.0, 0.0, 0.0]))


def test_an_orientation_the_solver_calls_solved_but_is_off_the_normal_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    """Levenberg-Marquardt may stop and report success short of eq. 13: the camera axis it gives must lie on the normal
    within 1e-9 rad, else the answer is refused (the closed form is then used). Here the solver's answer is 2e-6 rad off."""
    real = scipy.optimize.least_squares

    def short(*args: Any, **kwargs: Any) -> Any:
        sol = real(*args, **kwargs)
        sol.x = sol.x + np.array([0.0, 2e-6, 0.0])
        return sol

    monkeypatch.setattr(orientation, "least_squares", short)
    n = np.array([0.96, 0.2, -0.1]) / np.linalg.norm([0.96, 0.2, -0.1])
    with pytest.raises(AlignmentError, match="did not solve eq. 13"):
        solve_orientation_lm(rot_y(np.pi / 2), np.array([0.0, 0.0, 1.0]), n)
    monkeypatch.setattr(orientation, "least_squares", real)
    assert solve_orientation_lm(rot_y(np.pi / 2), np.array([0.0, 0.0, 1.0]), n).axis_error_rad < 1e-9


def test_the_plane_is_refitted_until_the_spots_it_uses_no_longer_change() -> None:
    """The consensus takes all eight spots; their least-squares plane leaves spot 0 beyond the 0.5 mm limit. The fit is
    repeated without it, so the plane reported is the least-squares plane of exactly the spots it says it used, and
    each of them lies within the limit of it."""
    yz = np.array([[-1500.0, -60.0], [-500.0, -60.0], [60.0, 300.0], [60.0, 1200.0], [-1000.0, 1560.0], [-2060.0, 750.0],
                   [-300.0, 700.0], [-1700.0, 100.0]])  # fmt: skip
    x = np.array([1000.46, 999.988, 999.698, 999.903, 1000.102, 999.925, 1000.204, 999.4985])
    P = np.column_stack([x, yz])
    all_eight = fit_plane(P)
    assert abs(all_eight.distance(P[0])) > 0.5  # the first refit drops spot 0
    wall = fit_wall_plane(P, SENSOR, inlier_threshold_mm=0.5)
    assert wall.inliers == (1, 2, 3, 4, 5, 6, 7)
    own = fit_plane(P[list(wall.inliers)])
    assert angle_between_vectors(wall.normal, own.normal if own.normal[0] > 0 else -own.normal) < 1e-12
    assert np.all(np.abs(wall.plane.distance(P[list(wall.inliers)])) <= 0.5)
    assert [r.index for r in wall.rejected] == [0]
