"""On-the-fly laser readings: interpolation, pairing and the latency estimate, against a trajectory built here."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from cellctl.align.onthefly import (
    estimate_latency,
    flange_poses_at,
    pair_stored_readings,
    pose_samples_arrays,
)
from cellctl.ports import CartesianPose, PoseSample, StoredReadings

F64 = NDArray[np.float64]
NOISE_MM = 0.005
FEEDBACK_S = 0.004
CYCLE_S = 0.001
R_LASER = np.array([40.0, -10.0, 120.0])
L_LASER = np.array([0.05, -0.03, 1.0]) / np.linalg.norm([0.05, -0.03, 1.0])
# Tool z points down at the wall; the wall's normal (pointing away from the sensor) is tilted 3 deg.
R_DOWN = Rotation.from_euler("x", 180, degrees=True)
WALL_N = Rotation.from_euler("xy", [3.0, -2.0], degrees=True).apply([0.0, 0.0, -1.0])
WALL_D = float(WALL_N @ np.array([0.0, 0.0, 130.0]))


def ramp(t: F64, length: float, v: float, a: float) -> F64:
    """Distance along a rest-to-rest move with a trapezoidal speed (closed form, mm)."""
    ta = v / a
    T = length / v + ta
    t = np.clip(t, 0.0, T)
    return np.where(
        t < ta, 0.5 * a * t**2, np.where(t <= T - ta, v * (t - 0.5 * ta), length - 0.5 * a * (T - t) ** 2)
    )


def legs_duration(legs: list[F64], v: float, a: float) -> float:
    return sum(float(np.linalg.norm(g)) / v + v / a for g in legs)


def true_poses(t: F64, legs: list[F64], v: float = 250.0, a: float = 2500.0, turn_deg: float = 1.5) -> F64:
    """Flange poses (M, 4, 4): straight legs one after another from (0, 0, 600), turning about a tilted axis."""
    t = np.asarray(t, dtype=float)
    p = np.zeros((t.size, 3)) + [0.0, 0.0, 600.0]
    start = 0.0
    for g in legs:
        length = float(np.linalg.norm(g))
        p += ramp(t - start, length, v, a)[:, None] * (g / length)
        start += length / v + v / a
    angle = np.radians(turn_deg) * np.clip(t / start, 0.0, 1.0)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    R = (Rotation.from_rotvec(angle[:, None] * axis) * R_DOWN).as_matrix()
    out = np.zeros((t.size, 4, 4))
    out[:, :3, :3], out[:, :3, 3], out[:, 3, 3] = R, p, 1.0
    return out


def true_distances(T: F64) -> F64:
    """Where the beam r + d l meets the wall: d = (D - n.o) / (n.u)."""
    o = np.einsum("nij,j->ni", T[:, :3, :3], R_LASER) + T[:, :3, 3]
    u = np.einsum("nij,j->ni", T[:, :3, :3], L_LASER)
    return (WALL_D - o @ WALL_N) / (u @ WALL_N)


CALIBRATION = [np.array([60.0, 0.0, -60.0]), np.array([0.0, 60.0, 60.0])]  # toward + sideways, away + sideways


def record(delta_s: float, legs: list[F64] = CALIBRATION, seed: int = 0) -> dict:
    """Feedback every 4 ms over the move and 0.1 s either side; stored readings every 1 ms, true at t - delta."""
    rng = np.random.default_rng(seed)
    end = legs_duration(legs, 250.0, 2500.0) + 0.1
    st = np.arange(-0.1, end, FEEDBACK_S)
    started = -0.08
    instants = started + CYCLE_S * np.arange(int((end - 0.02 - started) / CYCLE_S))
    d = true_distances(true_poses(instants - delta_s, legs)) + rng.normal(0.0, NOISE_MM, instants.size)
    return {"st": st, "sT": true_poses(st, legs), "instants": instants, "d": d, "started": started}


@pytest.mark.parametrize("delta_ms", [5.0, 8.0, 10.0, 12.0, 15.0, 10.37])  # 10.37: off the coarse grid
def test_latency_is_recovered_far_within_a_millisecond(delta_ms: float) -> None:
    rec = record(delta_ms / 1e3, seed=int(delta_ms))
    est = estimate_latency(rec["instants"], rec["d"], rec["st"], rec["sT"], R_LASER, L_LASER)
    err_ms = (est.latency_s - delta_ms / 1e3) * 1e3
    assert abs(err_ms) < 0.02  # typically a few microseconds
    assert 0.0 < est.sigma_s * 1e3 < 0.01
    assert abs(err_ms) < 5 * est.sigma_s * 1e3 + 0.005  # sigma is honest (plus the interpolation's bias)
    assert est.rms_mm < 1.5 * NOISE_MM
    assert abs(abs(est.normal @ WALL_N) - 1.0) < 1e-6


def stored_and_samples(rec: dict, blanks: tuple[int, ...] = ()) -> tuple[StoredReadings, tuple[PoseSample, ...]]:
    d = [None if k in blanks else float(x) for k, x in enumerate(rec["d"])]
    stored = StoredReadings(rec["started"], CYCLE_S, tuple(d))
    samples = tuple(PoseSample(float(t), CartesianPose.from_matrix(T)) for t, T in zip(rec["st"], rec["sT"]))
    return stored, samples


def test_paired_points_lie_on_the_wall_with_the_estimate_and_not_without_it() -> None:
    rec = record(0.010, seed=3)
    stored, samples = stored_and_samples(rec)
    est = estimate_latency(rec["instants"], rec["d"], rec["st"], rec["sT"], R_LASER, L_LASER)
    on_wall = pair_stored_readings(stored, samples, est.latency_s).points(R_LASER, L_LASER) @ WALL_N - WALL_D
    uncompensated = pair_stored_readings(stored, samples, 0.0).points(R_LASER, L_LASER) @ WALL_N - WALL_D
    assert np.sqrt(np.mean(on_wall**2)) < 1.5 * NOISE_MM
    assert np.sqrt(np.mean(uncompensated**2)) > 0.3  # 10 ms at up to 177 mm/s along the beam: ~1 mm


def test_interpolation_follows_the_trajectory_between_samples() -> None:
    st = np.arange(0.0, 0.6, FEEDBACK_S)
    mid = st[:-1] + 0.37 * FEEDBACK_S
    got = flange_poses_at(st, true_poses(st, CALIBRATION), mid)
    want = true_poses(mid, CALIBRATION)
    # Linear positions at 4 ms: at most a h^2 / 8 = 2500 * 0.004^2 / 8 = 0.005 mm off the curve.
    assert np.max(np.linalg.norm(got[:, :3, 3] - want[:, :3, 3], axis=1)) < 0.006
    angle = Rotation.from_matrix(np.swapaxes(got[:, :3, :3], 1, 2) @ want[:, :3, :3]).magnitude()
    assert np.max(angle) < 1e-9  # the turn is uniform about one axis: Slerp is exact
    np.testing.assert_allclose(flange_poses_at(st, true_poses(st, CALIBRATION), st[[0, 7, -1]]),
                               true_poses(st[[0, 7, -1]], CALIBRATION), atol=1e-9)


def test_interpolation_refuses_instants_outside_the_samples_and_unordered_samples() -> None:
    st = np.arange(0.0, 0.1, FEEDBACK_S)
    sT = true_poses(st, CALIBRATION)
    with pytest.raises(ValueError, match=r"instant 0\.2 s \(index 1\) is outside"):
        flange_poses_at(st, sT, [0.05, 0.2])
    with pytest.raises(ValueError, match="instant -0.001 s"):
        flange_poses_at(st, sT, [-0.001])
    with pytest.raises(ValueError, match="increase strictly"):
        flange_poses_at(st[::-1], sT[::-1], [0.05])


def test_pose_samples_are_sorted_and_repeats_dropped() -> None:
    T = true_poses(np.array([0.0, 0.004, 0.008]), CALIBRATION)
    samples = [PoseSample(t, CartesianPose.from_matrix(T[i])) for i, t in ((1, 0.004), (0, 0.0), (1, 0.004), (2, 0.008))]
    t, poses = pose_samples_arrays(samples)
    np.testing.assert_array_equal(t, [0.0, 0.004, 0.008])
    np.testing.assert_allclose(poses, T, atol=1e-9)


def test_pairing_drops_blank_readings_and_those_outside_the_feedback() -> None:
    rec = record(0.010, seed=4)
    stored, samples = stored_and_samples(rec, blanks=(30, 31, 500))
    latency = 0.03  # the first readings' shifted instants fall before the feedback starts at -0.1 s
    paired = pair_stored_readings(stored, samples, latency)
    q = rec["instants"] - latency
    expect = [k for k in range(q.size) if k not in (30, 31, 500) and -0.1 <= q[k] <= rec["st"][-1] + 1e-12]
    assert q[0] < -0.1 and 0 not in expect and 30 not in expect and 500 not in expect
    np.testing.assert_array_equal(paired.indices, expect)
    np.testing.assert_allclose(paired.instants, rec["instants"][expect])
    np.testing.assert_allclose(paired.distances, rec["d"][expect])
    np.testing.assert_allclose(paired.poses, true_poses(q[expect], CALIBRATION), atol=0.01)
    late = pair_stored_readings(stored, samples, -0.05)  # now the last readings fall after the feedback ends
    assert late.indices[-1] < q.size - 1 and late.instants[-1] + 0.05 <= rec["st"][-1]


def test_pairing_guesses_no_pose_across_a_gap_in_the_feedback() -> None:
    rec = record(0.010, seed=5)
    stored, samples = stored_and_samples(rec)
    hole = (0.30, 0.36)  # 60 ms without a sample: 15 lost at 4 ms
    holed = tuple(s for s in samples if not hole[0] < s.t_s < hole[1])
    q = rec["instants"] - 0.010
    across = np.flatnonzero((q > hole[0]) & (q < hole[1]))
    assert across.size > 10
    guessed = pair_stored_readings(stored, holed, 0.010)  # without a bound the hole is bridged ...
    assert np.isin(across, guessed.indices).all()
    bounded = pair_stored_readings(stored, holed, 0.010, max_gap_s=0.02)  # ... with one it is not
    assert not np.isin(across, bounded.indices).any()
    lost = np.setdiff1d(guessed.indices, bounded.indices)
    near = (q[lost] > hole[0] - FEEDBACK_S) & (q[lost] < hole[1] + FEEDBACK_S)
    assert near.all()  # only readings between the two samples around the hole are lost


def test_a_move_parallel_to_the_wall_is_refused() -> None:
    legs = [np.array([80.0, 0.0, 0.0]), np.array([0.0, 80.0, 0.0])]
    rec = record(0.010, legs=legs)
    flat = true_poses(rec["st"], legs, turn_deg=0.0)
    # A wall parallel to the path (the flange keeps its height and attitude): the distance never changes.
    assert np.ptp(flat[:, 2, 3]) < 1e-9 and np.ptp(flat[:, :3, :3], axis=0).max() < 1e-12
    rec_d = np.full(rec["instants"].size, 350.0) + np.random.default_rng(1).normal(0, NOISE_MM, rec["instants"].size)
    with pytest.raises(ValueError, match="not observable.*distances barely change.*toward the wall"):
        estimate_latency(rec["instants"], rec_d, rec["st"], flat, R_LASER, L_LASER)


def test_a_constant_speed_move_across_a_tilted_wall_is_refused() -> None:
    # Straight at constant speed: every point shifts by the same v * latency, which only moves the plane.
    st = np.arange(0.0, 1.0, FEEDBACK_S)
    sT = np.repeat(true_poses(np.zeros(1), CALIBRATION, turn_deg=0.0), st.size, axis=0)
    sT[:, 0, 3] += 200.0 * st
    sT[:, 1, 3] += 150.0 * st
    instants = np.arange(0.1, 0.9, CYCLE_S)
    d = true_distances(flange_poses_at(st, sT, instants - 0.01))
    with pytest.raises(ValueError, match="not observable"):
        estimate_latency(instants, d, st, sT, R_LASER, L_LASER)


def test_a_move_along_the_beam_at_one_spot_is_refused() -> None:
    legs = [-60.0 * (R_DOWN.as_matrix() @ L_LASER), 60.0 * (R_DOWN.as_matrix() @ L_LASER)]
    rec = record(0.010, legs=legs)
    flat = true_poses(rec["st"], legs, turn_deg=0.0)
    d = true_distances(true_poses(rec["instants"] - 0.01, legs, turn_deg=0.0))
    with pytest.raises(ValueError, match="line or one spot"):
        estimate_latency(rec["instants"], d, rec["st"], flat, R_LASER, L_LASER)


def test_a_latency_outside_the_search_range_is_refused() -> None:
    rec = record(0.010)
    with pytest.raises(ValueError, match="edge of the search range"):
        estimate_latency(rec["instants"], rec["d"], rec["st"], rec["sT"], R_LASER, L_LASER, search_s=(0.0, 0.006))
