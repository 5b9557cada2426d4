"""Timing and checking the laser's latency in a sweep, against moves along the beam built here with a known latency.

The flange stands at one spot of a tilted wall and moves 40 mm in (and out and in) along the laser beam; the
feedback reports its path every 4 ms, and the laser stores a reading every 2 ms that reflects the flange
``TRUE_S`` earlier. The sweep's own latency step (cellctl.cell.sweep._latency) must find that latency, or refuse.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from cellctl.align.beam_timing import estimate_latency_at_spot
from cellctl.align.onthefly import MIN_READINGS, LatencyEstimate, TimingReadings
from cellctl.cell.cycle_failure import CycleFailed
from cellctl.cell.laser_timing import LaserTiming
from cellctl.cell.sweep import _latency
from cellctl.domain import AlarmCode, CycleStep
from cellctl.geometry.motion import TrapezoidProfile

F64 = NDArray[np.float64]
R_LASER = np.array([40.0, -10.0, 120.0])
L_LASER = np.array([0.05, -0.03, 1.0]) / np.linalg.norm([0.05, -0.03, 1.0])
R_FLANGE = (Rotation.from_euler("xy", [4.0, -3.0], degrees=True) * Rotation.from_euler("x", 180, degrees=True)).as_matrix()
BEAM = R_FLANGE @ L_LASER
WALL_N = Rotation.from_euler("xy", [2.0, -1.5], degrees=True).apply([0.0, 0.0, -1.0])
WALL_D = float(WALL_N @ np.array([0.0, 0.0, 130.0]))
FEEDBACK_S, STORAGE_S, SETTLE_S = 0.004, 0.002, 0.15


def flange(t: F64, moves: int) -> F64:
    """(M, 4, 4) the flange at ``t``: 0.1 s standing 40 mm out, then ``moves`` moves of 40 mm in/out along the beam."""
    profile = TrapezoidProfile(40.0, 1000.0, 2000.0)
    along = np.full(t.size, -40.0)
    start = 0.1
    for k in range(moves):
        sign = 1.0 if k % 2 == 0 else -1.0
        along += sign * np.array([profile.travelled(float(np.clip(x - start, 0.0, profile.duration))) for x in t])
        start += profile.duration + SETTLE_S
    out = np.tile(np.eye(4), (t.size, 1, 1))
    out[:, :3, :3] = R_FLANGE
    out[:, :3, 3] = np.array([0.0, 0.0, 600.0]) + along[:, None] * BEAM
    return out


def record(true_s: float, moves: int, noise_mm: float, seed: int = 0) -> tuple[F64, F64, F64, F64, tuple[float, float]]:
    """(instants, distances, feedback instants, feedback poses, the approach's window) of the moves along the beam."""
    profile = TrapezoidProfile(40.0, 1000.0, 2000.0)
    end = 0.1 + moves * (profile.duration + SETTLE_S)
    st = np.arange(-0.2, end + 0.1, FEEDBACK_S)
    instants = np.arange(0.0, end, STORAGE_S)
    T = flange(instants - true_s, moves)
    o = np.einsum("nij,j->ni", T[:, :3, :3], R_LASER) + T[:, :3, 3]
    d = (WALL_D - o @ WALL_N) / (BEAM @ WALL_N) + np.random.default_rng(seed).normal(0.0, noise_mm, instants.size)
    return instants, d, st, flange(st, moves), (0.0, end)


def cell_run(max_sigma_s: float = 0.0005) -> SimpleNamespace:
    sweep = SimpleNamespace(path_mm=[(-1500.0, -100.0)], latency_search_s=(-0.01, 0.05), max_latency_sigma_s=max_sigma_s)
    return SimpleNamespace(process=SimpleNamespace(align=SimpleNamespace(sweep=sweep)), cal=SimpleNamespace(laser_r=R_LASER, laser_l=L_LASER))


def test_a_check_finds_a_latency_that_changed_beyond_its_narrow_search_in_the_whole_range() -> None:
    # kept: 7.3 ms; the laser now answers 7.7 ms later (another averaging on the controller): 15.0 ms, beyond 7.3 +- 5 ms
    instants, d, st, sT, window = record(0.0150, moves=1, noise_mm=0.002)
    est = _latency(cell_run(), CycleStep.ALIGN, instants, d, (st, sT), window, 0.0073)  # type: ignore[arg-type]
    assert abs(1e3 * est.latency_s - 15.0) < 0.1, est


def test_a_timing_whose_readings_scatter_too_much_is_refused_and_a_clean_one_is_not() -> None:
    instants, d, st, sT, window = record(0.0100, moves=3, noise_mm=3.0, seed=1)  # a wall that scatters 3 mm
    with pytest.raises(CycleFailed) as failed:
        _latency(cell_run(), CycleStep.ALIGN, instants, d, (st, sT), window, None)  # type: ignore[arg-type]
    assert failed.value.code is AlarmCode.ALIGNMENT_FAILED and "uncertain by" in failed.value.reason
    instants, d, st, sT, window = record(0.0100, moves=3, noise_mm=0.002, seed=1)
    est = _latency(cell_run(), CycleStep.ALIGN, instants, d, (st, sT), window, None)  # type: ignore[arg-type]
    assert abs(1e3 * est.latency_s - 10.0) < 0.1 and est.sigma_s < 0.0005, est


def test_fewer_readings_than_the_timing_needs_are_refused_counting_only_those_with_a_distance() -> None:
    instants, d, st, sT, _ = record(0.0100, moves=1, noise_mm=0.002)
    moving = np.flatnonzero((instants > 0.12) & (instants < 0.3))[: MIN_READINGS + 5]
    assert moving.size == MIN_READINGS + 5
    d_some_blank = d[moving].copy()
    d_some_blank[:6] = np.nan  # 19 readings with a distance
    with pytest.raises(ValueError, match=rf"only {MIN_READINGS - 1} readings .* need {MIN_READINGS}"):
        TimingReadings.checked(instants[moving], d_some_blank, st, sT, R_LASER, L_LASER, (-0.01, 0.05))
    kept = TimingReadings.checked(instants[moving[:MIN_READINGS]], d[moving[:MIN_READINGS]], st, sT, R_LASER, L_LASER, (-0.01, 0.05))
    assert kept.instants.size == MIN_READINGS


def _estimate(latency_s: float) -> LatencyEstimate:
    return LatencyEstimate(latency_s, 2e-5, 0.003, 500, 40.0)


def test_a_check_that_finds_the_latency_shorter_than_the_kept_one_disagrees_too() -> None:
    timing, laser, robot = LaserTiming(), object(), object()
    timing.timed(_estimate(0.0073), laser, robot)
    used, figures = timing.checked(_estimate(0.0053), 0.001)  # 2 ms earlier: the laser answers sooner now
    assert used == 0.0053 and figures["agrees"] is False and figures["off_ms"] == pytest.approx(-2.0)
    assert "5.30 ms against the kept 7.30 ms" in (timing.why_time(laser, robot, 25) or "")


def test_the_timings_sigma_is_the_scatter_of_its_estimate_over_repeated_moves() -> None:
    # in, out and in along the beam, the laser scattering 0.05 mm: twelve repeats, each its own draw of the noise
    errors_s, sigmas_s = [], []
    for seed in range(12):
        instants, d, st, sT, _ = record(0.0100, moves=3, noise_mm=0.05, seed=seed)
        est = estimate_latency_at_spot(TimingReadings.checked(instants, d, st, sT, R_LASER, L_LASER, (-0.01, 0.05)))
        errors_s.append(est.latency_s - 0.0100)
        sigmas_s.append(est.sigma_s)
    scatter_s = float(np.sqrt(np.mean(np.square(errors_s))))
    assert 0.5 < scatter_s / float(np.mean(sigmas_s)) < 2.0, (1e3 * scatter_s, 1e3 * float(np.mean(sigmas_s)))
