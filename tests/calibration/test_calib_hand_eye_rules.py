"""Hand-eye T_H_C: rules of the Tsai-Lenz solver, the motion checks and the method comparison, against synthetic views of
known truth (a board fixed in B, flange poses around it, the board pose each view sees through the true X)."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.calibration import hand_eye
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.hand_eye import evaluate_hand_eye, motion_pairs, solve_hand_eye, tsai_lenz
from cellctl.config.calibration_procedure import HandEyeCalibrationConfig
from cellctl.geometry.pose import invert_pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix, rotation_angle_between

AXIS = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
T_X = [-54.874, -75.193, 102.960]  # the paper's hand-eye translation (eq. 18)
T_B_P = make_pose(axis_angle_to_matrix([0.4, -0.2, 0.9]), [1500.0, 200.0, 900.0])


def _mounting(angle_deg: float) -> np.ndarray:
    return make_pose(axis_angle_to_matrix(AXIS * np.deg2rad(angle_deg)), T_X)


def _flange_poses(n: int, rng: np.random.Generator, tilt_deg: tuple[float, float] = (5.0, 45.0)) -> list[np.ndarray]:
    H = []
    for _ in range(n):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = np.deg2rad(rng.uniform(*tilt_deg)) * rng.choice([-1.0, 1.0])
        H.append(make_pose(axis_angle_to_matrix(axis * angle), rng.uniform(-800.0, 800.0, 3)))
    return H


def _views(X: np.ndarray, H: list[np.ndarray], rng: np.random.Generator | None = None, noise_rad: float = 0.0) -> list[np.ndarray]:
    """The board pose each flange pose sees through X; with ``noise_rad``, each disturbed by that (and 100x in mm)."""
    C = []
    for h in H:
        c = invert_pose(h @ X) @ T_B_P
        if rng is not None and noise_rad:
            c = c @ make_pose(axis_angle_to_matrix(rng.normal(0.0, noise_rad, 3)), rng.normal(0.0, 100.0 * noise_rad, 3))
        C.append(c)
    return C


def _error_deg(est: np.ndarray, X: np.ndarray) -> float:
    return float(np.degrees(rotation_angle_between(est[:3, :3], X[:3, :3])))


def test_a_mounting_a_hair_from_180_deg_is_found_as_well_as_one_at_120() -> None:
    # Tsai's first pass finds P' = tan(theta/2) * axis, which grows without bound near 180 deg: on the same noisy views
    # the rotation's error there must stay as small as at a well-conditioned mounting.
    errors = []
    for angle in (120.0, 179.9999):
        X = _mounting(angle)
        H = _flange_poses(10, np.random.default_rng(5))
        C = _views(X, H, np.random.default_rng(6), noise_rad=1e-5)
        pairs = motion_pairs(H, C, min_pair_angle_rad=np.deg2rad(5.0))
        errors.append(_error_deg(tsai_lenz(pairs.A, pairs.B), X))
    assert errors[0] < 0.002
    assert errors[1] < 1.5 * errors[0], errors


def test_tsai_needs_two_motion_pairs() -> None:
    # One motion leaves the rotation about its axis free: there is no answer to give.
    X = _mounting(121.0)
    H = _flange_poses(2, np.random.default_rng(1))
    pairs = motion_pairs(H, _views(X, H), min_pair_angle_rad=np.deg2rad(5.0))
    assert len(pairs.A) == 1
    with pytest.raises(ValueError, match="at least 2 motion pairs"):
        tsai_lenz(pairs.A, pairs.B)


def test_pairs_turned_nearly_half_a_turn_do_not_spoil_the_result() -> None:
    # A relative turn a hair under 180 deg seen through noisy board poses may come out a hair over it, that is as the
    # same turn about the opposite axis: such a pair's A and B give Tsai axes of opposite sign. They are left out, and
    # the views give X to their noise (0.0006 deg per board pose here), as the views without those pairs do.
    X = _mounting(121.0)
    for seed in (1, 2, 3):
        H = _flange_poses(8, np.random.default_rng(9 + seed))
        for k, axis in enumerate(([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.6, 0.0, 0.8])):
            H.append(H[k] @ make_pose(axis_angle_to_matrix(np.array(axis) * (np.pi - 2e-6)), [30.0, -20.0, 10.0]))
        C = _views(X, H, np.random.default_rng(20 + seed), noise_rad=1e-5)
        pairs = motion_pairs(H, C, min_pair_angle_rad=np.deg2rad(5.0))
        assert _error_deg(tsai_lenz(pairs.A, pairs.B), X) < 0.01, seed


def test_exactly_min_views_are_taken_and_give_the_true_mounting() -> None:
    X = _mounting(121.0)
    H = _flange_poses(6, np.random.default_rng(2))
    rep = solve_hand_eye(H, _views(X, H), methods=("tsai",), limits=HandEyeCalibrationConfig(min_views=6))
    assert _error_deg(rep.T_H_C, X) < 1e-6
    assert np.linalg.norm(rep.T_H_C[:3, 3] - X[:3, 3]) < 1e-4


def test_views_that_turn_the_flange_less_than_the_least_turn_are_refused() -> None:
    # Tilts of 3-6 deg about axes spread in 3-D: pairs turn 5-12 deg, enough pairs and axis spread, but too little turn
    # to see X's rotation through the robot's and the camera's noise.
    X = _mounting(121.0)
    H = _flange_poses(10, np.random.default_rng(3), tilt_deg=(3.0, 6.0))
    with pytest.raises(CalibrationRefused) as err:
        solve_hand_eye(H, _views(X, H), methods=("tsai",))
    assert err.value.reason == "rotations_too_small"


def test_the_residuals_of_the_true_mounting_are_zero_and_of_a_wrong_one_its_error() -> None:
    X = _mounting(121.0)
    H = _flange_poses(10, np.random.default_rng(4))
    C = _views(X, H)
    pairs = motion_pairs(H, C, min_pair_angle_rad=np.deg2rad(5.0))
    true = evaluate_hand_eye(X, H, C, pairs)
    assert true.rotation_rms_deg < 1e-6 and true.translation_rms_mm < 1e-6
    assert true.board_spread_mm < 1e-6 and true.board_spread_deg < 1e-6
    wrong = evaluate_hand_eye(X @ make_pose(np.eye(3), [1.0, 0.0, 0.0]), H, C, pairs)
    assert wrong.rotation_rms_deg < 1e-6  # a shift of X turns nothing
    assert 0.1 < wrong.translation_rms_mm < 2.0  # and moves each pair's residual by up to 2 |shift| sin(turn / 2)


def test_a_method_off_in_rotation_only_is_left_out_and_refused_when_chosen(monkeypatch: pytest.MonkeyPatch) -> None:
    # OpenCV's Park replaced by one turned 0.3 deg about the camera's origin: its translation is the truth (0 mm off, under
    # the 1 mm limit), its rotation 0.3 deg off (over the 0.1 deg limit). It is named as left out, and refused as chosen.
    X = _mounting(121.0)
    H = _flange_poses(12, np.random.default_rng(7))
    C = _views(X, H)
    turned = X @ make_pose(axis_angle_to_matrix(np.deg2rad(0.3) * np.array([0.0, 0.0, 1.0])), [0.0, 0.0, 0.0])
    real = hand_eye.opencv_hand_eye
    monkeypatch.setattr(hand_eye, "opencv_hand_eye", lambda h, c, m: turned if m == "opencv_park" else real(h, c, m))
    methods = ("tsai", "opencv_tsai", "opencv_park", "opencv_horaud", "opencv_daniilidis")
    rep = solve_hand_eye(H, C, methods=methods)
    assert "opencv_park" in rep.outliers
    assert hand_eye.refuse_disagreement(rep, HandEyeCalibrationConfig())[1] < 0.01
    rep = solve_hand_eye(H, C, chosen="opencv_park", methods=methods)
    with pytest.raises(CalibrationRefused) as err:
        hand_eye.refuse_disagreement(rep, HandEyeCalibrationConfig())
    assert err.value.reason == "methods_disagree"


def test_three_methods_of_five_that_agree_are_not_outvoted_by_two_strays(monkeypatch: pytest.MonkeyPatch) -> None:
    # Five methods ran (Andreff can fail on an orbit and leave five): Tsai, OpenCV's Tsai and Horaud find the true mounting,
    # Park and Andreff stand 20 and 40 mm off it. Each good method has two of its four others at 0 mm: it agrees; the
    # strays are left out and the chosen Tsai is taken. Of four others, the mean of the middle two (an agreeing one and a
    # stray) would put every method 10 mm or more from the others and refuse a good calibration as inconsistent data.
    X = _mounting(121.0)
    H = _flange_poses(12, np.random.default_rng(7))
    C = _views(X, H)
    stray = {"opencv_park": X @ make_pose(np.eye(3), [20.0, 0.0, 0.0]), "opencv_andreff": X @ make_pose(np.eye(3), [0.0, -40.0, 0.0])}
    real = hand_eye.opencv_hand_eye
    monkeypatch.setattr(hand_eye, "opencv_hand_eye", lambda h, c, m: stray[m] if m in stray else real(h, c, m))
    rep = solve_hand_eye(H, C, methods=("tsai", "opencv_tsai", "opencv_horaud", "opencv_park", "opencv_andreff"))
    assert sorted(rep.outliers) == ["opencv_andreff", "opencv_park"]
    hand_eye.refuse_disagreement(rep, HandEyeCalibrationConfig())
    chosen = rep.solutions[rep.chosen].T_H_C
    assert np.linalg.norm(chosen[:3, 3] - X[:3, 3]) < 1e-6 and _error_deg(chosen, X) < 1e-6
    # two of five agreeing are no majority: the chosen one is refused
    stray["opencv_horaud"] = X @ make_pose(np.eye(3), [0.0, 0.0, 30.0])
    rep = solve_hand_eye(H, C, methods=("tsai", "opencv_tsai", "opencv_horaud", "opencv_park", "opencv_andreff"))
    with pytest.raises(CalibrationRefused) as err:
        hand_eye.refuse_disagreement(rep, HandEyeCalibrationConfig())
    assert err.value.reason == "methods_disagree"


@pytest.mark.parametrize("axis", [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.3, -0.5, 0.8]])
def test_a_mounting_turned_exactly_half_a_turn_is_found_from_noise_free_views(axis: list[float]) -> None:
    # A camera mounted turned 180 deg (a drawing's Rz(180)): Tsai's P' = tan(theta/2) axis is unbounded there, so a
    # first pass solved at the half turn itself broke down (180 deg and a metre off, and the methods then disagreed).
    X = make_pose(axis_angle_to_matrix(np.pi * np.asarray(axis) / np.linalg.norm(axis)), T_X)
    H = _flange_poses(10, np.random.default_rng(5))
    C = _views(X, H)
    pairs = motion_pairs(H, C, min_pair_angle_rad=np.deg2rad(5.0))
    est = tsai_lenz(pairs.A, pairs.B)
    assert _error_deg(est, X) < 1e-7 and np.linalg.norm(est[:3, 3] - X[:3, 3]) < 1e-6
    rep = solve_hand_eye(H, C)
    hand_eye.refuse_disagreement(rep, HandEyeCalibrationConfig())
    assert _error_deg(rep.solutions["tsai"].T_H_C, X) < 1e-7
