"""Paper 4.3 compensation against a known workpiece displacement."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.compensate import (
    CorrectionLimitError,
    TaughtPoses,
    check_correction,
    corrected_workpiece_frame,
    deviation_in_frame,
    install_pose,
    shooting_pose_in,
    workpiece_frame_after_alignment,
)
from cellctl.geometry import make_pose, pose_from_xyz_fixed, rot_z
from cellctl.geometry.planar import PlanarOffset

T0 = pose_from_xyz_fixed([1700.0, -1000.0, 1800.0], -np.pi / 2, 0.0, -np.pi / 2)
C_POS_0 = T0 @ pose_from_xyz_fixed([30.0, -20.0, -480.0], 0.1, 0.05, 2.9)
G_POS_0 = T0 @ pose_from_xyz_fixed([-1000.0, 750.0, -120.0], 0.0, 0.0, 0.0)
TAUGHT = TaughtPoses(T0, C_POS_0, G_POS_0)


def test_no_displacement_gives_back_the_taught_install_pose() -> None:
    T1 = workpiece_frame_after_alignment(TAUGHT, C_POS_0)
    np.testing.assert_allclose(T1, T0, atol=1e-9)
    T2 = corrected_workpiece_frame(T1, PlanarOffset(0.0, 0.0, 0.0))
    np.testing.assert_allclose(install_pose(TAUGHT, T2), G_POS_0, atol=1e-9)


def test_a_moved_workpiece_is_followed_exactly() -> None:
    # The car body moved: true frame T_true. Alignment put the camera at the taught relation to a
    # frame that matches T_true up to an in-plane offset, which vision then measures.
    move = pose_from_xyz_fixed([12.0, -7.0, 25.0], 0.02, -0.03, 0.01)
    T_true = T0 @ move
    inplane = make_pose(rot_z(0.004), [1.5, -2.25, 0.0])
    T1_expected = T_true @ np.linalg.inv(inplane)
    C_Pos_1 = shooting_pose_in(TAUGHT, T1_expected)
    T1 = workpiece_frame_after_alignment(TAUGHT, C_Pos_1)
    np.testing.assert_allclose(T1, T1_expected, atol=1e-9)
    T2 = corrected_workpiece_frame(T1, PlanarOffset(1.5, -2.25, 0.004))
    np.testing.assert_allclose(T2, T_true, atol=1e-9)
    target = install_pose(TAUGHT, T2)
    dt, dr = deviation_in_frame(T_true @ TAUGHT.T_T0_gpos0, target)
    assert np.abs(dt).max() < 1e-9 and np.abs(dr).max() < 1e-12


def test_correction_limits_refuse_large_moves() -> None:
    far = G_POS_0 @ make_pose(np.eye(3), [0.0, 0.0, 80.0])
    with pytest.raises(CorrectionLimitError, match="install pose moves 80.00 mm"):
        check_correction(G_POS_0, far, max_translation_mm=50.0, max_rotation_rad=0.1, what="install pose")
    size = check_correction(G_POS_0, far, max_translation_mm=100.0, max_rotation_rad=0.1, what="install pose")
    assert size.translation_mm == pytest.approx(80.0)


def test_deviation_six_figures() -> None:
    ref = pose_from_xyz_fixed([1, 2, 3], 0.3, 0.2, 0.1)
    T = ref @ pose_from_xyz_fixed([0.1, -0.2, 0.3], 0.003, -0.002, 0.001)
    dt, dr = deviation_in_frame(ref, T)
    np.testing.assert_allclose(dt, [0.1, -0.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(dr, [0.001, -0.002, 0.003], atol=1e-12)
