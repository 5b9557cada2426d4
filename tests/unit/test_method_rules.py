"""One test per method rule, each against constructed geometry whose right answer is known.

The wall in every test is the plane x = 1000 mm (base frame), seen from the x < 1000 side, so the
true normal into the wall is +x and D = 1000 mm unless a test says otherwise.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from service_test_support import sim_config

import cellctl.align
from cellctl.align import (
    AlignmentError,
    FlangeOrientation,
    compute_alignment,
    correct_distance,
    fit_wall_plane,
    offset_at_rest,
)
from cellctl.cell.cycle import CycleRun
from cellctl.cell.cycle_failure import CycleFailed
from cellctl.compensate import CorrectionLimitError, TaughtPoses, check_correction
from cellctl.domain import AlarmCode, CycleStep
from cellctl.geometry import angle_between_vectors, make_pose, rot_y, rot_z
from cellctl.ports import DeviceRejected, UnreachableTarget

WALL_X = 1000.0
# Four wall spots, no three of them collinear.
WALL_SPOTS = np.array([[WALL_X, 0.0, 0.0], [WALL_X, 500.0, 50.0], [WALL_X, 30.0, 480.0], [WALL_X, 520.0, 530.0]])
SENSOR_FRONT = np.array([600.0, 250.0, 250.0])  # the sensor's side: x < 1000
SENSOR_BEHIND = np.array([1400.0, 250.0, 250.0])
R_LOOK_X = rot_y(np.pi / 2)  # flange/camera z axis along +x, i.e. into the wall


def test_correction_beyond_the_rotation_limit_is_refused_even_within_the_translation_limit() -> None:
    """Paper 4.3 safety rule: refuse a correction whose translation OR rotation exceeds its limit."""
    taught = make_pose(np.eye(3), [1500.0, -200.0, 900.0])
    turned = taught @ make_pose(rot_z(0.2), [0.0, 0.0, 0.0])  # turns 0.2 rad, does not move
    with pytest.raises(CorrectionLimitError, match="moves 0.00 mm"):
        check_correction(taught, turned, max_translation_mm=100.0, max_rotation_rad=0.1, what="install pose")
    size = check_correction(taught, turned, max_translation_mm=100.0, max_rotation_rad=0.3, what="install pose")
    assert size.translation_mm == pytest.approx(0.0, abs=1e-9)
    assert size.rotation_rad == pytest.approx(0.2, abs=1e-12)


def test_a_corrected_pose_that_is_not_a_number_is_refused_by_the_last_limit() -> None:
    """The correction limit is the last guard before the robot moves: a NaN from a failed measurement fails it."""
    taught = make_pose(np.eye(3), [1500.0, -200.0, 900.0])
    lost = taught.copy()
    lost[0, 3] = np.nan
    with pytest.raises(CorrectionLimitError, match="moves nan mm"):
        check_correction(taught, lost, max_translation_mm=100.0, max_rotation_rad=0.1, what="install pose")


def _standing_spots() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Flange poses 400 mm in front of the wall looking along +x, laser on the flange z axis."""
    yz = np.array([[0.0, 0.0], [500.0, 50.0], [30.0, 480.0], [520.0, 530.0], [250.0, 250.0]])
    poses = np.array([make_pose(R_LOOK_X @ rot_z(0.05), [WALL_X - 400.0, y, z]) for y, z in yz])
    return poses, np.full(len(yz), 400.0), np.zeros(3), np.array([0.0, 0.0, 1.0])


def test_lm_and_closed_form_orientations_must_agree_on_the_camera_axis(monkeypatch: pytest.MonkeyPatch) -> None:
    """Eq. 13 cross-check: an LM solution whose camera axis differs from the closed form's is refused."""
    poses, d, r, l = _standing_spots()  # noqa: E741
    T_H_C = np.eye(4)
    # Both solvers agree: the camera ends up looking along the true normal, 400 mm from the wall.
    res = compute_alignment(poses, d, r, l, T_H_C, 400.0)
    assert angle_between_vectors((res.T_B_H_aligned @ T_H_C)[:3, 2], [1.0, 0.0, 0.0]) < 1e-9
    real_lm = cellctl.align.solve_orientation_lm

    def tilted_lm(R0: np.ndarray, z_C: np.ndarray, normal: np.ndarray) -> FlangeOrientation:
        good = real_lm(R0, z_C, normal)
        R = rot_z(0.01) @ good.R_B_H  # camera axis 0.01 rad off the normal
        return FlangeOrientation(R, good.angles_rad, 0.0, "lm", good.iterations)

    monkeypatch.setattr(cellctl.align, "solve_orientation_lm", tilted_lm)
    with pytest.raises(AlignmentError, match="disagree on the camera axis by 0.01 rad"):
        compute_alignment(poses, d, r, l, T_H_C, 400.0)


def test_rest_reading_off_the_plane_does_not_move_the_offset() -> None:
    """Offset at rest (eq. 2 mean of n.p): only rest points within the inlier threshold count."""
    wall = fit_wall_plane(WALL_SPOTS, SENSOR_FRONT)  # plane on the move: D = 1000
    rng = np.random.default_rng(7)
    true_D = WALL_X + 0.2  # at rest the wall reads 0.2 mm deeper than on the move
    rest = np.column_stack([np.full(12, true_D), rng.uniform(0, 500, 12), rng.uniform(0, 500, 12)])
    rib = np.array([[true_D - 3.0, 260.0, 240.0]])  # one rest reading on a rib, 3 mm in front
    moved = offset_at_rest(wall, np.vstack([rest, rib]), inlier_threshold_mm=0.5, min_points=10)
    assert moved.offset == pytest.approx(true_D, abs=1e-9)
    assert moved.rest_shift_mm == pytest.approx(0.2, abs=1e-9)
    np.testing.assert_allclose(moved.normal, [1.0, 0.0, 0.0], atol=1e-12)


def test_consensus_tie_between_two_surfaces_is_refused() -> None:
    """Robust fit before eq. 2-11: two groups of spots as large as each other on two surfaces are no wall.

    Spots 0-3 hit a recessed panel 20 mm deep, one of them 0.4 mm off the others' plane (a bump);
    spots 4-7 hit the flat wall exactly. Both sets give 4 inliers: no majority tells which is the wall.
    """
    panel = np.array([[1020.0, -700, -300], [1020.0, -250, -350], [1020.0, -650, -800], [1020.4, -200, -750]])
    with pytest.raises(AlignmentError, match="only 4 of 8 spots agree on one plane"):
        fit_wall_plane(np.vstack([panel, WALL_SPOTS]), SENSOR_FRONT, inlier_threshold_mm=0.5)


def test_normal_points_away_from_the_sensor_on_either_side() -> None:
    """The paper's reversal rule (section 3.1): the normal points into the wall, away from the sensor."""
    front = fit_wall_plane(WALL_SPOTS, SENSOR_FRONT)
    np.testing.assert_allclose(front.normal, [1.0, 0.0, 0.0], atol=1e-12)
    assert front.offset == pytest.approx(WALL_X)
    behind = fit_wall_plane(WALL_SPOTS, SENSOR_BEHIND)  # same spots, sensor on the other side
    np.testing.assert_allclose(behind.normal, [-1.0, 0.0, 0.0], atol=1e-12)
    assert behind.offset == pytest.approx(-WALL_X)
    for wall, sensor in ((front, SENSOR_FRONT), (behind, SENSOR_BEHIND)):
        assert wall.plane.distance(sensor) < 0  # the sensor is in front, the wall lies along +normal


def test_sensor_on_both_sides_of_the_plane_is_refused() -> None:
    """Reversal rule (section 3.1): laser origins on both sides of the fitted plane cannot be oriented."""
    with pytest.raises(AlignmentError, match="both sides"):
        fit_wall_plane(WALL_SPOTS, np.vstack([SENSOR_FRONT, SENSOR_BEHIND]))


def test_camera_behind_the_wall_is_refused() -> None:
    """Eq. 14 precondition: the optical centre must be in front of the fitted wall (distance > 0)."""
    wall = fit_wall_plane(WALL_SPOTS, SENSOR_FRONT)
    T_H_C = make_pose(np.eye(3), [0.0, 0.0, 150.0])  # camera 150 mm ahead of the flange along z
    in_front = make_pose(R_LOOK_X, [WALL_X - 600.0, 200.0, 200.0])  # optical centre at x = 550
    ok = correct_distance(in_front, T_H_C, wall.plane, 400.0)
    assert ok.distance_before_mm == pytest.approx(450.0) and ok.delta_d_mm == pytest.approx(50.0)
    behind = make_pose(R_LOOK_X, [WALL_X - 100.0, 200.0, 200.0])  # flange in front, optical centre at x = 1050
    with pytest.raises(AlignmentError, match="50.0 mm behind the fitted wall"):
        correct_distance(behind, T_H_C, wall.plane, 400.0)


# The taught workpiece frame T0 and its shooting and gripping poses for the install tests.
INSTALL_T0 = make_pose(np.eye(3), [2000.0, 0.0, 1500.0])
INSTALL_TAUGHT = TaughtPoses(
    INSTALL_T0, INSTALL_T0 @ make_pose(np.eye(3), [-300.0, 200.0, -400.0]),
    INSTALL_T0 @ make_pose(np.eye(3), [-1000.0, 750.0, -120.0]),
)


async def test_an_install_pose_beyond_the_correction_limit_is_refused_before_the_robot_moves() -> None:
    """Paper 4.3: T2 @ inv(T0) @ g_Pos_0 is checked against g_Pos_0 before the install starts (limits.max_correction_mm)."""
    cfg = sim_config(**{"process.limits": {"max_correction_mm": 10.0}})
    T0, taught = INSTALL_T0, INSTALL_TAUGHT
    calls: list[str] = []

    class Robot:
        async def move(self, request: Any, *, timeout_s: float) -> Any:
            calls.append("move")
            return request.target

    class Recorder:
        async def install_started(self, target: Any) -> None:
            calls.append("install started")

    run = CycleRun(SimpleNamespace(robot=Robot()), SimpleNamespace(taught=taught), cfg.process, cfg.vision, Recorder())  # type: ignore[arg-type]
    with pytest.raises(CycleFailed) as refused:
        await run.install(T0 @ make_pose(np.eye(3), [30.0, 0.0, 0.0]))  # the car body 30 mm along
    assert refused.value.code is AlarmCode.CORRECTION_LIMIT_EXCEEDED and "install pose moves 30.00 mm" in refused.value.reason
    assert calls == []  # nothing recorded as started, the robot never asked to move
    target, _ = await run.install(T0 @ make_pose(np.eye(3), [5.0, 0.0, 0.0]))  # within the limit: it goes on
    np.testing.assert_allclose(target[:3, 3] - taught.g_Pos_0[:3, 3], [5.0, 0.0, 0.0], atol=1e-9)
    assert calls == ["install started", "move", "move"]


async def test_the_install_goes_into_the_opening_at_the_fine_speed() -> None:
    """The approach pose at the travel speed with the glass, the last move into the opening at process.motion's
    fine_speed_mm_s (the glass meets the opening's edges there)."""
    cfg = sim_config(**{"process.motion": {"fine_speed_mm_s": 20.0, "travel_speed_mm_s": 400.0}})
    T0, taught = INSTALL_T0, INSTALL_TAUGHT
    speeds: list[float] = []

    class Robot:
        async def move(self, request: Any, *, timeout_s: float) -> Any:
            speeds.append(request.speed_mm_s)
            return request.target

    class Recorder:
        async def install_started(self, target: Any) -> None: ...

    run = CycleRun(SimpleNamespace(robot=Robot()), SimpleNamespace(taught=taught), cfg.process, cfg.vision, Recorder())  # type: ignore[arg-type]
    await run.install(T0 @ make_pose(np.eye(3), [2.0, -1.0, 0.5]))
    assert speeds == [400.0, 20.0]


async def test_a_target_the_robot_cannot_reach_is_a_correction_for_the_operator_not_a_robot_fault() -> None:
    """The controller refusing a target out of reach means the car body stands where the correction cannot go: the
    cell holds for the operator (CORRECTION_LIMIT_EXCEEDED) instead of aborting on a robot fault; other refusals
    and failures of a move stay robot faults."""
    cfg = sim_config()
    refusals = iter([UnreachableTarget("robot", "MOVEL target refused: out of reach", "130 REACH"),
                     DeviceRejected("robot", "MOVEL refused: busy", "110 BUSY")])  # fmt: skip

    class Robot:
        async def move(self, request: Any, *, timeout_s: float) -> Any:
            raise next(refusals)

    run = CycleRun(SimpleNamespace(robot=Robot()), SimpleNamespace(), cfg.process, cfg.vision, None)  # type: ignore[arg-type]
    with pytest.raises(CycleFailed) as out_of_reach:
        await run.move(CycleStep.ALIGN, make_pose(np.eye(3), [1500.0, 0.0, 900.0]))
    assert out_of_reach.value.code is AlarmCode.CORRECTION_LIMIT_EXCEEDED and "out of reach" in out_of_reach.value.reason
    with pytest.raises(CycleFailed) as busy:
        await run.move(CycleStep.ALIGN, make_pose(np.eye(3), [1500.0, 0.0, 900.0]))
    assert busy.value.code is AlarmCode.ROBOT_FAULT
