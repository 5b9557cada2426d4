"""Hand-eye T_H_C: our Tsai-Lenz against the twin's mounting, OpenCV's methods beside it, refusals."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from calib_test_support import board_views, config, store_with_camera

from cellctl.calibration.compute import compute_hand_eye
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.hand_eye import (
    motion_diversity,
    motion_pairs,
    opencv_hand_eye,
    solve_hand_eye,
    tsai_lenz,
)
from cellctl.calibration.poses import plan_board_views
from cellctl.config.calibration_procedure import HandEyeCalibrationConfig
from cellctl.geometry.pose import invert_pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix, rotation_angle_between
from cellctl.sim.cell import SimCell
from cellctl.sim.targets import Checkerboard, place_on_world_plane


def _random_pose(rng: np.random.Generator, angle_deg: tuple[float, float], t_mm: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = np.deg2rad(rng.uniform(*angle_deg)) * rng.choice([-1.0, 1.0])
    return make_pose(axis_angle_to_matrix(axis * angle), rng.uniform(-t_mm, t_mm, 3))


def _synthetic(X: np.ndarray, n: int, rng: np.random.Generator, *, one_axis: np.ndarray | None = None) -> tuple[list, list]:
    """Exact eye-in-hand data: board fixed in B, flange poses around it, board seen from X."""
    T_B_P = _random_pose(rng, (5, 85), 1500.0)
    H, C = [], []
    for _ in range(n):
        if one_axis is None:
            Hk = _random_pose(rng, (5, 45), 800.0)
        else:
            Hk = make_pose(axis_angle_to_matrix(one_axis * np.deg2rad(rng.uniform(-60, 60))), rng.uniform(-800, 800, 3))
        H.append(Hk)
        C.append(invert_pose(Hk @ X) @ T_B_P)
    return H, C


@pytest.mark.parametrize("angle_deg", [30.0, 121.0, 179.0])
def test_tsai_is_exact_on_exact_data_whatever_the_mounting(angle_deg: float) -> None:
    rng = np.random.default_rng(int(angle_deg))
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    X = make_pose(axis_angle_to_matrix(axis * np.deg2rad(angle_deg)), [-54.9, -75.2, 103.0])
    H, C = _synthetic(X, 8, rng)
    pairs = motion_pairs(H, C, min_pair_angle_rad=np.deg2rad(5.0))
    est = tsai_lenz(pairs.A, pairs.B)
    assert np.linalg.norm(est[:3, 3] - X[:3, 3]) < 1e-7
    assert rotation_angle_between(est[:3, :3], X[:3, :3]) < 1e-9


def test_hand_eye_recovers_the_mounting_and_opencv_agrees() -> None:
    ds, dets = board_views()
    store = store_with_camera()
    o = compute_hand_eye(ds, store.current(), config(), dets)
    X_true = np.asarray(ds.manifest["twin_truth"]["T_H_C"])
    X = np.asarray(o.values["T_H_C"])
    # The robot poses are the controller's beliefs (absolute-accuracy field and repeatability
    # in them); the camera sees the truth.
    assert np.linalg.norm(X[:3, 3] - X_true[:3, 3]) < 0.5
    assert np.degrees(rotation_angle_between(X[:3, :3], X_true[:3, :3])) < 0.05
    methods = o.quality["methods"]
    assert set(methods) == {"tsai", "opencv_tsai", "opencv_park", "opencv_horaud", "opencv_andreff", "opencv_daniilidis"}
    # OpenCV's own calibrateHandEye on the same data, every method near the truth and near ours.
    for m, q in o.quality["twin_truth"].items():
        assert q["translation_error_mm"] < 0.5 and q["rotation_error_deg"] < 0.05, m
    assert methods["opencv_tsai"]["from_chosen_mm"] < 0.05 and methods["opencv_tsai"]["from_chosen_deg"] < 0.01
    assert o.quality["motion"]["axis_spread"] > 0.3
    assert methods["tsai"]["chain_reprojection_rms_px"] < 2.0
    assert o.inputs == {"camera": store.current().parts.camera.id}


def test_opencv_methods_take_the_method_by_keyword() -> None:
    ds, dets = board_views()
    store = store_with_camera()
    cal = store.current()
    o = compute_hand_eye(ds, cal, config(), dets)
    # On noisy data the methods give (slightly) different answers: a method passed positionally
    # would silently run Tsai for all of them.
    park = np.asarray(o.quality["methods"]["opencv_park"]["translation_mm"])
    andreff = np.asarray(o.quality["methods"]["opencv_andreff"]["translation_mm"])
    assert np.linalg.norm(park - andreff) > 1e-6


def test_too_few_views_are_refused() -> None:
    rng = np.random.default_rng(3)
    X = make_pose(axis_angle_to_matrix([0.2, 0.1, 0.3]), [10.0, 20.0, 30.0])
    H, C = _synthetic(X, 4, rng)
    with pytest.raises(CalibrationRefused) as err:
        solve_hand_eye(H, C, limits=HandEyeCalibrationConfig(min_views=6))
    assert err.value.reason == "too_few_views"


def test_rotations_about_one_axis_are_refused() -> None:
    rng = np.random.default_rng(4)
    X = make_pose(axis_angle_to_matrix([0.2, 0.1, 0.3]), [10.0, 20.0, 30.0])
    H, C = _synthetic(X, 12, rng, one_axis=np.array([0.0, 0.0, 1.0]))
    d = motion_diversity(H)
    assert d.axis_spread < 1e-6
    with pytest.raises(CalibrationRefused) as err:
        solve_hand_eye(H, C)
    assert err.value.reason == "one_rotation_axis"
    assert "about one axis" in str(err.value)
    # Why it is refused: OpenCV on the same data cannot find the translation along that axis
    # (Tsai gives a wrong one, Park NaN, which is refused as a solver failure).
    X_cv = opencv_hand_eye(H, C, "opencv_tsai")
    assert abs(X_cv[2, 3] - X[2, 3]) > 1.0
    with pytest.raises(CalibrationRefused) as err2:
        opencv_hand_eye(H, C, "opencv_park")
    assert err2.value.reason == "solver_failed"


def test_board_not_found_in_any_view_is_refused() -> None:
    ds, dets = board_views()
    store = store_with_camera()
    blank = [(name, type(d)(False, None, "no board")) for name, d in dets]
    with pytest.raises(CalibrationRefused) as err:
        compute_hand_eye(ds, store.current(), config(), blank)
    assert err.value.reason == "board_not_found"


def test_planned_views_are_reachable_show_the_board_and_spread_their_axes() -> None:
    cfg = config()
    cell = SimCell(cfg.sim, seed=2)
    cc = cfg.calibration.procedure.camera
    intr = cfg.sim.camera.intrinsics
    plate = Checkerboard(inner_corners=cc.board.inner_corners, square_mm=cc.board.square_mm, border_mm=cc.board.border_mm)
    (cx, cy), (hx, hy) = plate.plate_rect()
    outline = np.array([[cx + sx * hx, cy + sy * hy, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    T_B_P = place_on_world_plane(cfg.sim.world.T_B_T_nominal(), cc.board_on_wall_mm)
    T_H_C = cfg.sim.camera.hand_eye.T_H_C()
    plan = plan_board_views(
        T_B_P, outline, T_H_C, intr.camera_matrix(), intr.dist_coeffs(), (2048, 2048), 12, cell.robot_model.check_reach
    )
    assert len(plan.flange_poses) == 12
    for X in plan.flange_poses:
        cell.robot_model.check_reach(X)  # raises if out of reach
        T_C_B = invert_pose(X @ T_H_C)
        pts = (T_C_B[:3, :3] @ (T_B_P[:3, :3] @ outline.T + T_B_P[:3, 3:4]) + T_C_B[:3, 3:4]).T
        uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), intr.camera_matrix(), intr.dist_coeffs())
        uv = uv.reshape(-1, 2)
        assert np.all(uv >= 0) and np.all(uv <= 2047)
    d = motion_diversity(plan.flange_poses)
    assert d.axis_spread > 0.3 and d.max_pair_angle_deg > 30.0
