"""Timing the laser from moves along its beam, against a trajectory and a wall built here.

The robot's true flange leaves the reported one as the twin's arm does: by an error drawn anew at
every stand, blended along each move, and at speed by a deflection across the path in proportion to
the speed (``DEFLECT_S`` times it, along a fixed axis made perpendicular to the path). The feedback
reports the commanded path.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from cellctl.align.beam_timing import estimate_latency_at_spot
from cellctl.align.onthefly import LatencyAtEdge, LatencyEstimate, TimingReadings, estimate_latency
from cellctl.geometry.motion import TrapezoidProfile

F64 = NDArray[np.float64]
R_LASER = np.array([40.0, -10.0, 120.0])
L_LASER = np.array([0.05, -0.03, 1.0]) / np.linalg.norm([0.05, -0.03, 1.0])
R_FLANGE = (Rotation.from_euler("xy", [4.0, -3.0], degrees=True) * Rotation.from_euler("x", 180, degrees=True)).as_matrix()
BEAM = R_FLANGE @ L_LASER
WALL_N = Rotation.from_euler("xy", [2.0, -1.5], degrees=True).apply([0.0, 0.0, -1.0])  # away from the sensor
WALL_D = float(WALL_N @ np.array([0.0, 0.0, 130.0]))
FEEDBACK_S, STORAGE_S, SETTLE_S, NOISE_MM = 0.004, 0.01, 0.15, 0.002
DEFLECT_S, DEFLECT_AXIS = 1e-4, np.array([0.3, -0.4, 0.87]) / np.linalg.norm([0.3, -0.4, 0.87])


def _path(legs: list[F64], speed_mm_s: float) -> tuple[list[F64], list[TrapezoidProfile], list[float]]:
    """The stands (mm), the legs' profiles and their start times (s): 0.1 s standing, then each leg and its settle."""
    stands = [np.array([0.0, 0.0, 600.0])]
    profiles, starts, t = [], [], 0.1
    for g in legs:
        stands.append(stands[-1] + g)
        profiles.append(TrapezoidProfile(float(np.linalg.norm(g)), speed_mm_s, 2000.0))
        starts.append(t)
        t += profiles[-1].duration + SETTLE_S
    return stands, profiles, starts


def _poses(t: F64, stands: list[F64], profiles: list[TrapezoidProfile], starts: list[float], errors: F64 | None) -> F64:
    """(M, 4, 4) flange poses at ``t``: the reported path, or with ``errors`` (per stand, mm) blended along each leg."""
    out = np.tile(np.eye(4), (t.size, 1, 1))
    out[:, :3, :3] = R_FLANGE
    for k, tk in enumerate(t):
        j = int(np.searchsorted(starts, tk, side="right")) - 1
        if j < 0:
            p, e = stands[0], None if errors is None else errors[0]
        else:
            f = profiles[j].travelled(tk - starts[j]) / profiles[j].distance
            p = stands[j] + f * (stands[j + 1] - stands[j])
            u = (stands[j + 1] - stands[j]) / profiles[j].distance
            across = DEFLECT_AXIS - (DEFLECT_AXIS @ u) * u
            speed = (profiles[j].travelled(tk - starts[j] + 1e-4) - profiles[j].travelled(tk - starts[j] - 1e-4)) / 2e-4
            e = None if errors is None else (1.0 - f) * errors[j] + f * errors[j + 1] + DEFLECT_S * speed * across / np.linalg.norm(across)
        out[k, :3, 3] = p if e is None else p + e
    return out


def _record(legs: list[F64], delta_s: float, *, seed: int, stand_sigma_mm: float = 0.03, speed_mm_s: float = 1000.0) -> dict:
    rng = np.random.default_rng(seed)
    stands, profiles, starts = _path(legs, speed_mm_s)
    end = starts[-1] + profiles[-1].duration + SETTLE_S
    errors = rng.normal(0.0, stand_sigma_mm, (len(stands), 3))
    st = np.arange(-0.1, end + 0.1, FEEDBACK_S)
    instants = rng.uniform(0.0, STORAGE_S) + np.arange(0.0, end, STORAGE_S)
    T = _poses(instants - delta_s, stands, profiles, starts, errors)
    o = np.einsum("nij,j->ni", T[:, :3, :3], R_LASER) + T[:, :3, 3]
    d = (WALL_D - o @ WALL_N) / (BEAM @ WALL_N) + rng.normal(0.0, NOISE_MM, instants.size)
    return {"instants": instants, "d": d, "st": st, "sT": _poses(st, stands, profiles, starts, None), "starts": starts}


def _at_spot(rec: dict, keep: NDArray[np.bool_] | None = None, search_s: tuple[float, float] = (-0.01, 0.05)) -> LatencyEstimate:
    k = np.ones(rec["instants"].size, dtype=bool) if keep is None else keep
    timed = TimingReadings.checked(rec["instants"][k], rec["d"][k], rec["st"], rec["sT"], R_LASER, L_LASER, search_s)
    return estimate_latency_at_spot(timed)


IN_OUT_IN = [40.0 * BEAM, -40.0 * BEAM, 40.0 * BEAM]


@pytest.mark.parametrize("delta_ms", [5.0, 7.3, 10.0, 12.0, 15.0])
def test_in_out_and_in_along_the_beam_times_the_laser_within_a_tenth_of_a_millisecond(delta_ms: float) -> None:
    rec = _record(IN_OUT_IN, delta_ms / 1e3, seed=int(10 * delta_ms))
    est = _at_spot(rec)
    err_ms = 1e3 * (est.latency_s - delta_ms / 1e3)
    assert abs(err_ms) < 0.1, err_ms
    assert abs(err_ms) < 4.0 * 1e3 * est.sigma_s + 0.02  # its sigma is honest
    assert est.normal is None and est.rms_mm < 0.05 and est.n > 50


def test_one_move_in_checks_a_kept_latency_as_well() -> None:
    rec = _record(IN_OUT_IN[:1], 0.0073, seed=5)
    est = _at_spot(rec, search_s=(0.0023, 0.0123))
    assert abs(1e3 * est.latency_s - 7.3) < 0.15


def test_the_robots_error_from_stop_to_stop_misleads_a_plane_over_the_legs_and_not_the_spot() -> None:
    # The approach at one spot, then an L along the tilted wall, each stand with its own draw of the robot's error:
    # the legs' plane takes the draws for latency; the approach's points stay on one spot at the true latency.
    legs = [*IN_OUT_IN[:1], np.array([1500.0, 0.0, 0.0]), np.array([0.0, 1200.0, 0.0]), np.array([0.0, -1200.0, 0.0])]
    errors: dict[str, list[float]] = {"plane": [], "spot": []}
    for seed in range(16):
        rec = _record(legs, 0.0073, seed=seed, stand_sigma_mm=0.04)
        plane = estimate_latency(rec["instants"], rec["d"], rec["st"], rec["sT"], R_LASER, L_LASER)
        approach = rec["instants"] <= rec["starts"][1]
        spot = _at_spot(rec, approach)
        errors["plane"].append(abs(1e3 * plane.latency_s - 7.3))
        errors["spot"].append(abs(1e3 * spot.latency_s - 7.3))
    assert max(errors["spot"]) < 0.1 and max(errors["plane"]) > 0.2, errors  # here: 0.045 and 0.24 ms
    assert np.mean(errors["spot"]) < np.mean(errors["plane"]) / 3.0, errors  # 0.015 against 0.091 ms


def test_a_flange_moving_across_the_beam_or_standing_is_refused_with_the_move_to_make() -> None:
    sideways = _record([np.array([0.0, 40.0, 0.0]) + 40.0 * BEAM], 0.0073, seed=1)
    with pytest.raises(ValueError, match="across the laser beam.*approach_mm"):
        _at_spot(sideways)
    still = _record([0.01 * BEAM], 0.0073, seed=2)
    with pytest.raises(ValueError, match="not observable"):
        _at_spot(still)
    rec = _record(IN_OUT_IN, 0.0073, seed=3)
    with pytest.raises(LatencyAtEdge):
        _at_spot(rec, search_s=(-0.01, 0.004))
