"""The lens model against OpenCV, and the line tools (fit, RANSAC, intersection, angle)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.config.mounting import CameraIntrinsics
from cellctl.vision.lens import Lens
from cellctl.vision.lines import Line2D, fit_line, intersect, line_angle_to_u, ransac_line

LENS = Lens.from_intrinsics(CameraIntrinsics())


def test_distort_matches_cv2_project_points() -> None:
    rng = np.random.default_rng(1)
    P = np.column_stack([rng.uniform(-80, 80, 200), rng.uniform(-80, 80, 200), rng.uniform(380, 420, 200)])
    expected, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), LENS.camera_matrix, LENS.dist_coeffs)
    ideal = np.column_stack([LENS.fx * P[:, 0] / P[:, 2] + LENS.cx, LENS.fy * P[:, 1] / P[:, 2] + LENS.cy])
    np.testing.assert_allclose(LENS.distort(ideal), expected.reshape(-1, 2), atol=1e-9)


def test_undistort_inverts_distort_over_the_whole_image() -> None:
    v, u = np.mgrid[0:2048:37, 0:2048:37].astype(float)
    raw = np.column_stack([u.ravel(), v.ravel()])
    ideal = LENS.undistort(raw)
    np.testing.assert_allclose(LENS.distort(ideal), raw, atol=1e-7)
    cv_ideal = cv2.undistortPointsIter(
        raw.reshape(-1, 1, 2), LENS.camera_matrix, LENS.dist_coeffs, None, LENS.camera_matrix,
        (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12),
    ).reshape(-1, 2)
    np.testing.assert_allclose(ideal, cv_ideal, atol=1e-5)
    # The corners of the image move by several pixels: the correction matters.
    assert np.max(np.linalg.norm(ideal - raw, axis=1)) > 5.0


def test_lens_refuses_bad_points() -> None:
    with pytest.raises(ValueError, match="shape"):
        LENS.undistort(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="NaN"):
        LENS.distort(np.array([[np.nan, 1.0]]))


def test_fit_line_recovers_a_noisy_line_with_its_uncertainty() -> None:
    rng = np.random.default_rng(2)
    d = np.array([np.cos(0.3), np.sin(0.3)])
    t = rng.uniform(-300, 300, 2000)
    p0 = np.array([100.0, 50.0])
    pts = p0 + t[:, None] * d + rng.normal(0, 0.1, 2000)[:, None] * np.array([-d[1], d[0]])
    fit = fit_line(pts)
    assert abs(abs(fit.line.direction @ d) - 1.0) < 1e-8
    assert abs(fit.line.signed_distance(p0[None])[0]) < 0.01
    assert fit.rms_px == pytest.approx(0.1, rel=0.05)
    # Predicted angle sigma: 0.1 / (spread * sqrt(N)); spread of U(-300, 300) is 300/sqrt(3).
    assert fit.sigma_angle_rad == pytest.approx(0.1 / (300 / np.sqrt(3) * np.sqrt(2000)), rel=0.1)


def test_ransac_ignores_outliers_and_is_reproducible() -> None:
    rng = np.random.default_rng(3)
    t = np.linspace(0, 500, 400)
    line = np.column_stack([t, 0.02 * t + 10 + rng.normal(0, 0.05, 400)])
    junk = rng.uniform(0, 500, (300, 2))
    pts = np.vstack([line, junk])
    m1 = ransac_line(pts, 0.3, 200, np.random.default_rng(7))
    m2 = ransac_line(pts, 0.3, 200, np.random.default_rng(7))
    np.testing.assert_array_equal(m1, m2)
    assert m1[:400].mean() > 0.98
    assert m1[400:].mean() < 0.05
    fit = fit_line(pts[m1])
    assert line_angle_to_u(fit.line.direction) == pytest.approx(np.arctan(0.02), abs=1e-4)


def test_intersection_and_angles() -> None:
    a = Line2D(np.array([0.0, 5.0]), np.array([1.0, 0.0]))
    b = Line2D(np.array([3.0, 0.0]), np.array([0.0, 1.0]))
    np.testing.assert_allclose(intersect(a, b), [3.0, 5.0])
    assert intersect(a, Line2D(np.array([0.0, 9.0]), np.array([-1.0, 0.0]))) is None
    assert line_angle_to_u([-1.0, -0.01]) == pytest.approx(np.arctan2(0.01, 1.0))
    assert line_angle_to_u([0.0, -1.0]) == pytest.approx(np.pi / 2)
