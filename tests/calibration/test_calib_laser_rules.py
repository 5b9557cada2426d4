"""Laser r and l: rules of calibrate_laser that the twin's runs do not pin down, against synthetic readings of known truth.

The readings are exact ray-plane intersections of the paper's laser (eq. 19: r, l in the flange frame) with a wall
z = 1500 mm in B, from flange poses tilted 10-35 deg about axes across the beam and spun about it; a robot that stands
elsewhere than it reports is a shift per arm stand (a group) that the readings see and the poses do not.
"""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.laser import calibrate_laser
from cellctl.config.calibration_procedure import LaserCalibrationConfig
from cellctl.geometry.pose import make_pose
from cellctl.geometry.rotation import angle_between_vectors, axis_angle_to_matrix

R_TRUE = np.array([43.6839, -40.4931, 90.1015])
L_TRUE = np.array([0.9977, 0.0626, 0.0265]) / np.linalg.norm([0.9977, 0.0626, 0.0265])
WALL_N, WALL_D = np.array([0.0, 0.0, 1.0]), 1500.0
R_NOM, L_NOM = [40.0, -40.0, 90.0], [1.0, 0.0, 0.0]  # the CAD mounting the fit starts from
LOOSE = LaserCalibrationConfig(min_poses=12, max_r_sigma_mm=1e3, max_l_sigma_deg=1e3)


def _readings(n: int, rng: np.random.Generator, *, groups: int = 1, group_shift_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(reported T_B_H, exact distances, group of each reading); each group's robot stands off by one random shift."""
    v = np.cross(L_TRUE, WALL_N)
    R0 = axis_angle_to_matrix(v / np.linalg.norm(v) * np.arccos(L_TRUE @ WALL_N))  # the beam square onto the wall
    shifts = rng.normal(0.0, group_shift_mm, (groups, 3))
    H, d, g = [], [], []
    for k in range(n):
        axis = np.append(rng.normal(size=2), 0.0)
        axis /= np.linalg.norm(axis)
        R = axis_angle_to_matrix(axis * np.deg2rad(rng.uniform(10, 35))) @ axis_angle_to_matrix(WALL_N * np.deg2rad(rng.uniform(-60, 60))) @ R0
        beam = R @ L_TRUE
        origin = np.append(rng.uniform(-100, 100, 2), WALL_D - rng.uniform(280, 420) * beam[2])
        t = origin - R @ R_TRUE
        true_origin = R @ R_TRUE + t + shifts[k % groups]
        H.append(make_pose(R, t))
        d.append((WALL_D - WALL_N @ true_origin) / (WALL_N @ beam))
        g.append(k % groups)
    return np.array(H), np.array(d), np.array(g)


def test_exactly_min_poses_readings_are_taken_and_one_fewer_refused() -> None:
    H, d, _ = _readings(13, np.random.default_rng(1))
    limits = LOOSE.model_copy(update={"min_poses": 13})
    res = calibrate_laser(H, d, R_NOM, L_NOM, limits=limits)
    assert np.linalg.norm(res.r - R_TRUE) < 1e-6
    with pytest.raises(CalibrationRefused) as err:
        calibrate_laser(H[:12], d[:12], R_NOM, L_NOM, limits=limits)
    assert err.value.reason == "too_few_poses"


def test_groups_labelled_by_sparse_stand_numbers_give_the_true_r_and_l() -> None:
    # The planner labels a reading's group by its arm stand's index into the wrist depths, so the labels skip the
    # stands no pose used; each label is one offset, whatever its number.
    H, d, g = _readings(60, np.random.default_rng(3), groups=4, group_shift_mm=0.5)
    with pytest.raises(CalibrationRefused) as err:  # the stands' shifts are there: one offset cannot take them
        calibrate_laser(H, d, R_NOM, L_NOM, limits=LOOSE)
    assert err.value.reason == "residual_too_high"
    res = calibrate_laser(H, d, R_NOM, L_NOM, groups=np.array([3, 7, 11, 20])[g], limits=LOOSE)
    assert np.linalg.norm(res.r - R_TRUE) < 1e-6
    assert np.degrees(angle_between_vectors(res.l, L_TRUE)) < 1e-6
    assert len(res.plane_offsets_mm) == 4


def test_readings_scattered_beyond_the_rms_limit_are_refused() -> None:
    # Readings of a surface 0.25 mm rough (or a robot that did not stand still): beyond the 0.1 mm limit, whatever r
    # and l the fit finds; the same poses read to 0.02 mm pass.
    H, d, _ = _readings(40, np.random.default_rng(5))
    noise = np.random.default_rng(6).normal(0.0, 1.0, len(d))
    with pytest.raises(CalibrationRefused) as err:
        calibrate_laser(H, d + 0.25 * noise, R_NOM, L_NOM, limits=LOOSE)
    assert err.value.reason == "residual_too_high"
    assert calibrate_laser(H, d + 0.02 * noise, R_NOM, L_NOM, limits=LOOSE).rms_mm < 0.03


def test_a_known_plane_with_groups_is_refused() -> None:
    H, d, g = _readings(20, np.random.default_rng(4), groups=2)
    with pytest.raises(ValueError, match="known plane has one offset"):
        calibrate_laser(H, d, R_NOM, L_NOM, groups=g, plane=(WALL_N, WALL_D), limits=LOOSE)


def test_the_reported_sigmas_of_r_and_l_match_their_scatter_over_noisy_repeats() -> None:
    # 14 readings and 8 unknowns (r, l, the plane's normal and offset): the noise variance is estimated over the
    # 6 degrees of freedom left, so the sigmas are neither too small nor, in degrees, off by a unit.
    H, d0, _ = _readings(14, np.random.default_rng(2))
    noise = np.random.default_rng(7)
    rs, l_err_deg, r_sig, l_sig = [], [], [], []
    for _ in range(100):
        res = calibrate_laser(H, d0 + noise.normal(0.0, 0.02, len(d0)), R_NOM, L_NOM, limits=LOOSE)
        rs.append(res.r)
        l_err_deg.append(np.degrees(angle_between_vectors(res.l, L_TRUE)))
        r_sig.append(res.r_sigma_mm)
        l_sig.append(res.l_sigma_deg)
    ratio_r = np.sqrt(np.mean(np.square(r_sig), axis=0)) / np.std(rs, axis=0)
    assert np.all((ratio_r > 0.8) & (ratio_r < 1.25)), ratio_r
    # l's error is an angle in 2-D: its RMS is the two axes' sigmas added in quadrature.
    ratio_l = np.hypot(*np.sqrt(np.mean(np.square(l_sig), axis=0))) / np.sqrt(np.mean(np.square(l_err_deg)))
    assert 0.8 < ratio_l < 1.25, ratio_l


def test_l_known_worse_than_its_limit_is_refused_though_r_is_within_its_own() -> None:
    # Over noisy repeats of these 14 readings l scatters about 0.07 deg RMS (the test above): a limit of 0.02 deg
    # must refuse them even with r's limit out of the way.
    H, d0, _ = _readings(14, np.random.default_rng(2))
    d = d0 + np.random.default_rng(8).normal(0.0, 0.02, len(d0))
    with pytest.raises(CalibrationRefused) as err:
        calibrate_laser(H, d, R_NOM, L_NOM, limits=LOOSE.model_copy(update={"max_l_sigma_deg": 0.02}))
    assert err.value.reason == "uncertain"


def test_a_linearity_curve_over_the_sensors_range_is_taken_out() -> None:
    # The sensor reads d + 0.04 mm * P2(u), u = -1..1 over its range 250-450 mm (the LK-G500's +-0.02 % of full scale
    # is a curve of this size): one Legendre term normalised to that range takes it out, r and l come out true.
    lo, hi = 250.0, 450.0
    H, d, _ = _readings(60, np.random.default_rng(12))
    u = (2.0 * d - (lo + hi)) / (hi - lo)
    read = d + 0.04 * np.polynomial.legendre.legval(u, [0.0, 0.0, 1.0])
    res = calibrate_laser(H, read, R_NOM, L_NOM, linearity_terms=1, distance_range_mm=(lo, hi), limits=LOOSE)
    # (not to the last bit: the model evaluates the curve at the reading, the sensor at the true distance)
    assert np.linalg.norm(res.r - R_TRUE) < 1e-3
    assert np.degrees(angle_between_vectors(res.l, L_TRUE)) < 1e-4
    assert res.linearity_coefficients_mm == pytest.approx([0.04], abs=1e-4)
    assert res.rms_mm < 1e-4
