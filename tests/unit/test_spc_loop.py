"""The closed-loop offset against known truth: a cell with a set bias and seeded noise, each rule of
cellctl.quality.spc with a test that fails without it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from spc_support import TOL_MM, ewma_sd, make_loop, simulate_loop

from cellctl.config.spc import SpcConfig
from cellctl.domain import InstallDeviation
from cellctl.geometry.pose import invert_pose, pose_from_xyz_fixed
from cellctl.geometry.rotation import xyz_fixed_to_matrix
from cellctl.quality import AXES, DriftKind, Exclusion, SpcEvent, SpcState, offset_pose

SIGMA = (0.03, 0.005)  # mm, deg: a cell's install scatter
BIAS = {"dx_mm": 0.12, "dy_mm": -0.08, "dz_mm": 0.0, "drx_deg": 0.03, "dry_deg": -0.02, "drz_deg": 0.0}
ZERO = dict.fromkeys(AXES, 0.0)


def _sigma(axis: str) -> float:
    return SIGMA[0] if axis.endswith("_mm") else SIGMA[1]


# -- what it estimates and applies ------------------------------------------------------------------


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_applied_offset_converges_to_the_bias_within_the_ewma_noise(seed: int) -> None:
    cfg = SpcConfig()
    run = simulate_loop(BIAS, SIGMA, 400, cfg, seed)
    for a in AXES:
        sd = ewma_sd(_sigma(a), cfg.ewma_lambda)  # sigma * sqrt(lambda / (2 - lambda))
        offset = run.series("offset", a)[60:]  # after the start's transient, (1 - lambda)^55 of it left
        # every offset within 5 sd of the truth (the dead band adds up to its width on an axis without bias)
        slack = cfg.dead_band_mm if a.endswith("_mm") else cfg.dead_band_deg
        assert np.max(np.abs(offset - BIAS[a])) <= 5 * sd + (slack if BIAS[a] == 0 else 0), a
        if BIAS[a]:
            assert abs(offset.mean() - BIAS[a]) <= sd, a  # ~33 independent values: the mean is 6x tighter
        # and the installs themselves lost their bias: what is measured now scatters around 0
        measured = run.series("measured", a)[60:]
        assert abs(measured.mean()) <= 0.25 * _sigma(a) + (slack if BIAS[a] == 0 else 0), a
    # the k = 4 gate drops a good result now and then (its sigma is itself estimated): ~1 in 3000 here
    assert run.state.n_excluded <= 2 and not run.state.drifting


def test_the_estimate_works_on_the_uncompensated_deviation() -> None:
    """u = measured + applied: with the offset applied, the estimate stays at the bias instead of
    decaying to what is left after its own correction."""
    loop = make_loop()
    run = simulate_loop({"dx_mm": 0.1}, (0.0, 0.0), 30, seed=0, loop=loop)
    assert run.state.estimate["dx_mm"] == pytest.approx(0.1)
    assert run.state.offset["dx_mm"] == pytest.approx(0.1)
    last = run.updates[-1].record
    assert last is not None and last.u is not None
    assert last.u["dx_mm"] == pytest.approx(run.measured[-1]["dx_mm"] + run.applied[-1]["dx_mm"])
    assert run.measured[-1]["dx_mm"] == pytest.approx(0.0)  # the install is right on
    # an install that really used another offset says so; u follows it
    up = loop.update(run.state, {**ZERO, "dx_mm": 0.05}, calibration_version="1", cycle_id=99, applied={**ZERO, "dx_mm": 0.02})
    assert up.record is not None and up.record.u is not None and up.record.u["dx_mm"] == pytest.approx(0.07)


def test_the_running_mean_is_applied_from_the_first_result() -> None:
    """Grubbs' harmonic rule: before the estimate starts, the mean of the uncompensated results so far
    is the offset, so the bias leaves after the first install (not after min_samples)."""
    cfg = SpcConfig(min_samples=7)
    bias = {"dx_mm": 0.1, "dry_deg": -0.03}
    run = simulate_loop(bias, SIGMA, 10, cfg, seed=4)
    for i, up in enumerate(run.updates[:6]):
        assert up.state.n_samples == i + 1 and not up.state.estimating
        for a in AXES:
            u = [run.measured[k][a] + run.applied[k][a] for k in range(i + 1)]
            mean = float(np.mean(u))
            dead = cfg.dead_band_mm if a.endswith("_mm") else cfg.dead_band_deg
            assert up.state.offset[a] == pytest.approx(0.0 if abs(mean) <= dead else mean), (i, a)
            assert run.applied[i + 1][a] == up.state.offset[a]
    assert all(run.applied[0][a] == 0.0 for a in AXES)
    # From the second install on, what is left of the bias is the first results' noise.
    for a, b in bias.items():
        left = np.mean([run.measured[k][a] for k in range(1, 7)])
        assert abs(left) < 0.4 * abs(b), a
    started = run.updates[6]
    assert started.events == (SpcEvent.ESTIMATE_STARTED,) and started.state.estimating
    for a in AXES:  # the estimate starts from the same mean
        assert started.state.estimate[a] == pytest.approx(np.mean([run.measured[k][a] + run.applied[k][a] for k in range(7)]))


def test_no_offset_before_min_samples_then_the_mean_of_them() -> None:
    cfg = SpcConfig(min_samples=7, warm_up_offset=False)
    run = simulate_loop({"dx_mm": 0.1, "dry_deg": -0.03}, SIGMA, 10, cfg, seed=4)
    for i, up in enumerate(run.updates[:6]):
        assert up.state.n_samples == i + 1 and not up.state.estimating
        assert up.state.offset == ZERO and SpcEvent.ESTIMATE_STARTED not in up.events
        assert all(run.applied[i][a] == 0.0 for a in AXES)
    started = run.updates[6]
    assert started.events == (SpcEvent.ESTIMATE_STARTED,) and started.state.estimating
    for a in AXES:  # nothing was applied yet: u is what was measured
        assert started.state.estimate[a] == pytest.approx(np.mean([m[a] for m in run.measured[:7]]))
    assert started.state.offset["dx_mm"] == pytest.approx(started.state.estimate["dx_mm"])
    assert started.offset_changed and run.applied[7]["dx_mm"] == started.state.offset["dx_mm"]


def test_a_bias_within_the_dead_band_applies_no_offset() -> None:
    cfg = SpcConfig()
    run = simulate_loop({"dx_mm": 0.012, "drz_deg": -0.003}, (0.002, 0.0003), 200, cfg, seed=5)
    assert np.allclose(run.series("offset", "dx_mm"), 0.0) and np.allclose(run.series("offset", "drz_deg"), 0.0)
    assert run.state.estimate["dx_mm"] == pytest.approx(0.012, abs=0.002)  # seen, not applied
    assert run.state.estimate["drz_deg"] == pytest.approx(-0.003, abs=0.0005)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_the_offset_is_clipped_at_max_offset(sign: float) -> None:
    cfg = SpcConfig()  # max 0.2 mm / 0.05 deg, drift 0.25 mm / 0.08 deg
    run = simulate_loop({"dy_mm": sign * 0.23, "drx_deg": sign * 0.065}, (0.005, 0.001), 150, cfg, seed=6)
    dy, drx = run.series("offset", "dy_mm"), run.series("offset", "drx_deg")
    assert np.all(np.abs(dy) <= cfg.max_offset_mm) and np.all(np.abs(drx) <= cfg.max_offset_deg)
    assert np.all(dy[20:] == sign * cfg.max_offset_mm) and np.all(drx[20:] == sign * cfg.max_offset_deg)
    assert run.state.estimate["dy_mm"] == pytest.approx(sign * 0.23, abs=0.005)  # the estimate is not clipped
    assert not run.state.drifting  # beyond the bound but within the drift limit
    assert np.mean(run.series("measured", "dy_mm")[20:]) == pytest.approx(sign * 0.03, abs=0.003)


def test_disabled_the_loop_watches_but_applies_nothing() -> None:
    cfg = SpcConfig(enabled=False)
    run = simulate_loop({"dx_mm": 0.3}, SIGMA, 40, cfg, seed=7)
    assert np.all(run.series("offset", "dx_mm") == 0.0)
    assert run.state.estimate["dx_mm"] == pytest.approx(0.3, abs=0.05)
    assert [d.axis for d in run.state.drifting] == ["dx_mm"]  # drift is still reported


def test_the_offset_pose_is_eq_13_in_the_workpiece_frame() -> None:
    off = {"dx_mm": 0.1, "dy_mm": -0.05, "dz_mm": 0.02, "drx_deg": 0.03, "dry_deg": -0.01, "drz_deg": 0.04}
    T = offset_pose(off)
    assert np.allclose(T[:3, 3], [0.1, -0.05, 0.02])
    R = xyz_fixed_to_matrix(math.radians(0.04), math.radians(-0.01), math.radians(0.03))  # Rz(drz) Ry(dry) Rx(drx)
    assert np.allclose(T[:3, :3], R, atol=1e-15)
    # a glass that lands at the deviation pose D lands on target once the target takes inv(offset)
    D = pose_from_xyz_fixed([0.1, -0.05, 0.02], *(math.radians(off[a]) for a in ("drz_deg", "dry_deg", "drx_deg")))
    assert np.allclose(D @ invert_pose(T), np.eye(4), atol=1e-12)
    assert np.allclose(make_loop().offset_pose(SpcState()), np.eye(4))


# -- drift -----------------------------------------------------------------------------------------


def test_a_step_beyond_the_gate_is_reported_as_drift_within_outlier_run_results() -> None:
    cfg = SpcConfig()

    def bias(i: int) -> dict[str, float]:  # the camera was knocked at result 100: +0.4 mm in x
        return {"dx_mm": 0.05 + (0.4 if i >= 100 else 0.0)}

    run = simulate_loop(bias, SIGMA, 130, cfg, seed=8)
    first = next(i for i, u in enumerate(run.updates) if u.drift_started)
    assert 100 <= first < 100 + cfg.outlier_run
    (drift,) = run.updates[first].drift_started
    assert (drift.axis, drift.kind, drift.limit) == ("dx_mm", DriftKind.STEP, cfg.drift_limit_mm)
    assert drift.value == pytest.approx(0.45, abs=0.15)
    assert SpcEvent.DRIFT in run.updates[first].events
    assert run.state.drifting == (drift,)  # latched, reported once
    assert sum(bool(u.drift_started) for u in run.updates) == 1
    assert np.all(np.abs(run.series("offset", "dx_mm")) <= cfg.max_offset_mm)


def test_a_trend_past_the_drift_limit_is_reported_and_the_offset_never_passes_its_bound() -> None:
    cfg = SpcConfig()
    rate = 0.003  # mm per install: a slow creep

    def bias(i: int) -> dict[str, float]:
        return {"dz_mm": rate * i}

    run = simulate_loop(bias, SIGMA, 150, cfg, seed=9)
    crossing = math.ceil(cfg.drift_limit_mm / rate)  # the truth passes the limit here (84)
    first = next(i for i, u in enumerate(run.updates) if u.drift_started)
    # not before the truth is near the limit, and soon after it passed (EWMA lag (1 - l) / l * rate = 4 installs)
    assert crossing - 10 <= first <= crossing + 15
    (drift,) = run.updates[first].drift_started
    assert (drift.axis, drift.kind) == ("dz_mm", DriftKind.TREND) and drift.value > cfg.drift_limit_mm
    dz = run.series("offset", "dz_mm")
    assert np.max(np.abs(dz)) == pytest.approx(cfg.max_offset_mm) and np.all(dz[first:] == cfg.max_offset_mm)
    assert run.state.drifting_axes == ("dz_mm",)


# -- what must not feed the loop --------------------------------------------------------------------


def test_the_outlier_gate_excludes_one_wild_value_and_counts_it() -> None:
    run = simulate_loop(BIAS, SIGMA, 80, seed=10, spikes={60: {"dy_mm": 0.3}})  # 10 sigma, within tolerance
    before, wild, after = run.updates[59], run.updates[60], run.updates[61]
    assert wild.excluded == Exclusion.OUTLIER and wild.record is not None and wild.record.excluded == Exclusion.OUTLIER
    assert wild.state.estimate == before.state.estimate and wild.state.offset == before.state.offset
    assert wild.state.n_samples == before.state.n_samples
    assert wild.state.excluded == {"outlier": 1} and run.state.n_excluded == 1
    assert wild.state.axes["dy_mm"].run == 1 and after.state.axes["dy_mm"].run == 0  # one, not a step
    assert not run.state.drifting


def test_results_that_must_not_feed_the_loop_are_excluded_with_their_reason() -> None:
    loop = make_loop()
    state = simulate_loop(BIAS, SIGMA, 30, seed=11, loop=loop).state
    cases = [
        (None, {}, Exclusion.NOT_INSTALLED),
        ({**BIAS}, {"reliable": False}, Exclusion.UNRELIABLE),
        ({**BIAS, "dz_mm": math.nan}, {}, Exclusion.NOT_FINITE),
        ({**BIAS, "dx_mm": TOL_MM + 0.01}, {}, Exclusion.BEYOND_TOLERANCE),
        ({**BIAS, "drz_deg": -1.2}, {}, Exclusion.BEYOND_TOLERANCE),
    ]
    for k, (dev, kw, reason) in enumerate(cases):
        up = loop.update(state, dev, calibration_version="1", cycle_id=100 + k, **kw)
        assert up.excluded == reason, reason
        assert up.state.estimate == state.estimate and up.state.n_samples == state.n_samples
        assert up.state.excluded[reason.value] >= 1 and up.state.last_cycle_id == 100 + k
        state = up.state
    assert state.excluded == {"not_installed": 1, "unreliable": 1, "not_finite": 1, "beyond_tolerance": 2}
    with pytest.raises(ValueError, match="lacks dz_mm; it needs all of"):
        loop.update(state, {a: 0.0 for a in AXES if a != "dz_mm"}, calibration_version="1", cycle_id=200)


def test_a_cycle_counted_once_even_if_fed_again() -> None:
    loop = make_loop()
    state = simulate_loop(BIAS, SIGMA, 10, seed=12, loop=loop).state  # cycles 1..10
    again = loop.update(state, BIAS, calibration_version="1", cycle_id=10)
    assert again.excluded == Exclusion.DUPLICATE and again.record is None and again.state is state
    dev = InstallDeviation(**BIAS)  # the domain's record works as well as a mapping
    assert loop.update(state, dev, calibration_version="1", cycle_id=11).state.n_samples == 11


# -- resets -----------------------------------------------------------------------------------------


def test_a_new_calibration_version_resets_the_loop() -> None:
    loop = make_loop()
    run = simulate_loop(BIAS, SIGMA, 60, seed=13, loop=loop, version=4)
    old = run.state
    assert old.calibration_version == "4" and old.offset["dx_mm"] != 0.0
    assert loop.offset(old, 5) == ZERO  # the offset belongs to version 4's calibration
    assert loop.offset(old, "4") == old.offset
    up = loop.update(old, {**ZERO, "dx_mm": 0.01}, calibration_version=5, cycle_id=61)
    assert up.reset == SpcEvent.RESET_CALIBRATION and up.events == (SpcEvent.RESET_CALIBRATION,)
    new = up.state
    assert new.calibration_version == "5" and new.reset_reason == SpcEvent.RESET_CALIBRATION
    assert new.n_samples == 1 and not new.estimating and new.offset == ZERO and new.excluded == {}
    assert new.axes["dx_mm"].warmup == (0.01,)  # nothing was applied under version 5: u = measured
    assert not up.offset_changed  # the install used version 5's offset: none
    # the same version again does nothing of the kind
    assert loop.update(new, ZERO, calibration_version="5", cycle_id=62).reset is None


def test_an_operator_reset_forgets_estimate_and_drift() -> None:
    loop = make_loop()
    run = simulate_loop({"dx_mm": 0.4}, SIGMA, 30, seed=14, loop=loop, version="v7")
    assert run.state.drifting and run.state.offset["dx_mm"] == pytest.approx(0.2)
    up = loop.reset(run.state)
    assert up.reset == SpcEvent.RESET_OPERATOR and up.offset_changed
    assert up.record is not None and up.record.events == (SpcEvent.RESET_OPERATOR,) and up.record.cycle_id is None
    s = up.state
    assert (s.calibration_version, s.n_samples, s.drifting, s.offset) == ("v7", 0, (), ZERO)
    assert s.last_cycle_id == 30  # a cycle counted before the reset still counts once


def test_the_loop_refuses_a_drift_limit_at_or_past_the_install_tolerance() -> None:
    with pytest.raises(ValueError, match=r"drift_limit_mm = 0.5 is not below .*position_mm = 0.5"):
        make_loop(SpcConfig(drift_limit_mm=0.5))


def test_a_cell_without_scatter_still_takes_results_within_the_sigma_floor() -> None:
    """The outlier gate assumes at least sigma_floor of noise (the measurement's resolution): after results with no
    scatter at all, a next one a little off is taken, not excluded as an outlier for ever after."""
    cfg = SpcConfig()
    loop = make_loop(cfg)
    state = simulate_loop({"dx_mm": 0.1}, (0.0, 0.0), 10, cfg, seed=0, loop=loop).state
    assert state.axes["dx_mm"].sigma == pytest.approx(0.0, abs=1e-12)
    off = cfg.outlier_k * cfg.sigma_floor_mm * 0.5  # within k floors of the estimate
    up = loop.update(state, {**ZERO, "dx_mm": off}, calibration_version="1", cycle_id=11)
    assert up.excluded is None and up.state.n_samples == state.n_samples + 1


def test_tolerance_is_judged_on_the_install_as_measured_not_on_the_uncompensated_deviation() -> None:
    """A cell whose bias the offset takes out: an install measured within tolerance is not "beyond tolerance", even
    when the deviation without the offset (u) would be."""
    loop = make_loop()
    state = simulate_loop({"dx_mm": 0.2}, SIGMA, 30, seed=5, loop=loop).state
    applied = loop.offset(state, "1")["dx_mm"]
    assert applied > 0.15
    measured = TOL_MM - 0.5 * applied  # within tolerance as installed; u = measured + applied is beyond it
    up = loop.update(state, {**ZERO, "dx_mm": measured}, calibration_version="1", cycle_id=31)
    assert up.excluded is not Exclusion.BEYOND_TOLERANCE
    over = loop.update(up.state, {**ZERO, "dx_mm": TOL_MM + 0.01}, calibration_version="1", cycle_id=32)
    assert over.excluded is Exclusion.BEYOND_TOLERANCE


def _sigma_ratios(n: int, seeds: range, start: int) -> np.ndarray:
    """The noise estimate over the truth, per cell (seed) and axis: its mean over results ``start`` to ``n``."""
    ratios = []
    for seed in seeds:
        run = simulate_loop({"dx_mm": 0.05, "dry_deg": 0.01}, SIGMA, n, seed=seed)
        for a in AXES:
            sig = np.array([u.state.axes[a].sigma for u in run.updates[start:]], dtype=float)
            ratios.append(sig.mean() / _sigma(a))
    return np.array(ratios)


def test_the_noise_estimate_is_the_installs_scatter_in_the_long_run() -> None:
    """A residual against the EWMA also carries the estimate's own noise: (2 - lambda) / 2 of its square is the
    installs' scatter. Over 20 cells x 6 axes x 1,200 results the estimate's mean is the true sigma within 1.2 %
    (0.997 here; 1.023 without the factor, at lambda = 0.1)."""
    assert abs(_sigma_ratios(1500, range(20), 300).mean() - 1.0) < 0.012


def test_the_first_noise_estimates_are_a_running_mean_of_the_residuals() -> None:
    """After the warm-up's few results, sigma goes on as a running mean of the residuals, not at once as the slow EWMA
    that would keep the warm-up's guess: 30 results in, within 16 % RMS of the truth over 40 cells x 6 axes (13 %
    here; 21 % with the slow weight from the start)."""
    ratios = _sigma_ratios(30, range(40), 29)
    assert float(np.sqrt(np.mean((ratios - 1.0) ** 2))) < 0.16
