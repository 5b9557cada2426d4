"""The twin's move along its path, the in-plane helpers and the laser head's range, against independent truth
(scipy's Slerp, the symmetry of a rest-to-rest profile, numpy's complex angle). Each fails with its rule removed."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from cellctl.align.errors import AlignmentError
from cellctl.align.laser_points import laser_points
from cellctl.geometry.motion import interpolate_pose, path_timing
from cellctl.geometry.planar import rot2, wrap_angle
from cellctl.geometry.pose import make_pose


def test_a_pose_partway_turns_about_the_fixed_axis_as_scipys_slerp_does() -> None:
    """A MoveL turns about one fixed axis: the start's rotation times a fraction of the relative turn, on the right."""
    rng = np.random.default_rng(3)
    for A_R, B_R in zip(Rotation.random(20, random_state=5), Rotation.random(20, random_state=6), strict=True):
        if (A_R.inv() * B_R).magnitude() > 0.9 * np.pi:  # near a half turn the shortest way is ambiguous
            continue
        a, b = rng.normal(0, 500, 3), rng.normal(0, 500, 3)
        A, B = make_pose(A_R.as_matrix(), a), make_pose(B_R.as_matrix(), b)
        slerp = Slerp([0.0, 1.0], Rotation.concatenate([A_R, B_R]))
        for s in (0.1, 0.37, 0.5, 0.9):
            P = interpolate_pose(A, B, s)
            np.testing.assert_allclose(P[:3, :3], slerp([s]).as_matrix()[0], atol=1e-12)
            np.testing.assert_allclose(P[:3, 3], (1 - s) * a + s * b, atol=1e-9)


def test_a_move_led_by_its_turn_is_halfway_at_half_time() -> None:
    """Whichever of translation and rotation takes longer leads the path fraction; its rest-to-rest profile is
    symmetric, so the flange is halfway along at half the path time. A short translation with a long turn must not
    follow the translation's profile (it would be at the end already)."""
    A = make_pose(np.eye(3), [0.0, 0.0, 0.0])
    B = make_pose(Rotation.from_rotvec([0, 0, np.radians(90)]).as_matrix(), [20.0, 0.0, 0.0])
    timing = path_timing(A, B, speed_mm_s=500.0, acceleration_mm_s2=2000.0, speed_rad_s=np.radians(30),
                         acceleration_rad_s2=np.radians(120), settle_s=0.1)  # fmt: skip
    assert timing.rotation.duration > 10 * timing.translation.duration  # the turn leads
    T = timing.path_s
    assert timing.fraction(0.5 * T) == pytest.approx(0.5, abs=1e-12)
    assert timing.fraction(0.25 * T) + timing.fraction(0.75 * T) == pytest.approx(1.0, abs=1e-12)
    # and the other way round: a long translation with a small turn
    C = make_pose(Rotation.from_rotvec([0, 0, np.radians(1)]).as_matrix(), [1500.0, 0.0, 0.0])
    timing = path_timing(A, C, speed_mm_s=500.0, acceleration_mm_s2=2000.0, speed_rad_s=np.radians(30),
                         acceleration_rad_s2=np.radians(120), settle_s=0.1)  # fmt: skip
    assert timing.translation.duration > timing.rotation.duration
    assert timing.fraction(0.5 * timing.path_s) == pytest.approx(0.5, abs=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1.0, -1.0, 3.0, -3.0, 3.5, -3.5, 4.7, -4.7, 7.0, -7.0, 12.9, 100.0])
def test_wrap_angle_is_numpys_complex_angle(angle: float) -> None:
    """[-pi, pi): the same direction as ``angle``, as numpy's angle of exp(i angle) gives it."""
    wrapped = wrap_angle(angle)
    assert -np.pi <= wrapped < np.pi
    assert wrapped == pytest.approx(float(np.angle(np.exp(1j * angle))), abs=1e-12)


def test_rot2_turns_x_towards_y() -> None:
    """The in-plane rotation of ``PlanarOffset`` (positive turns x towards y, as the image's u turns to v): the
    upper-left block of scipy's rotation about z."""
    for angle in (0.3, -1.2, 2.5):
        np.testing.assert_allclose(rot2(angle), Rotation.from_rotvec([0, 0, angle]).as_matrix()[:2, :2], atol=1e-15)
    np.testing.assert_allclose(rot2(np.pi / 2) @ [1.0, 0.0], [0.0, 1.0], atol=1e-15)


@pytest.mark.parametrize(("distance_mm", "refused"), [(249.9, True), (250.0, False), (450.0, False), (450.1, True), (120.0, True)])
def test_a_laser_distance_outside_the_heads_range_either_side_is_refused(distance_mm: float, refused: bool) -> None:
    """The head measures within its range only (the LK-G500: 250..450 mm): a reading nearer than its near end is
    as wrong as one beyond its far end, and neither becomes a wall point."""
    T = np.eye(4)[None].repeat(3, axis=0)
    r, l = np.zeros(3), np.array([0.0, 0.0, 1.0])  # noqa: E741
    d = [300.0, distance_mm, 300.0]
    if refused:
        with pytest.raises(AlignmentError, match=r"distances \[\(1, .*outside the sensor's range 250..450 mm"):
            laser_points(T, r, l, d, range_mm=(250.0, 450.0))
    else:
        np.testing.assert_allclose(laser_points(T, r, l, d, range_mm=(250.0, 450.0))[1], [0.0, 0.0, distance_mm])
