"""Per-axis statistics against hand-computed figures, and the budget's attribution."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.bench.stats import (
    AXES,
    axis_stats,
    error_matrix,
    normal_p99_abs,
    p99_difference_interval,
    within_tolerance_all_axes,
)

FIELDS = [a.field for a in AXES]


def _te(*values: float) -> dict[str, float]:
    return dict(zip(FIELDS, values))


def test_axis_stats_match_hand_computed_figures() -> None:
    errors = [_te(0.1, -0.2, 0.0, 0.5, 0.0, 0.0), _te(-0.3, 0.2, 0.0, -1.5, 0.0, 0.0), _te(0.2, 0.3, 0.0, 0.1, 0.0, 0.0)]
    st = {s.axis: s for s in axis_stats(errors, tolerance_mm=0.25, tolerance_deg=1.0)}
    x = st["X"]
    assert x.n == 3 and x.unit == "mm" and x.paper_max == 0.4 and x.tolerance == 0.25
    assert x.max_abs == pytest.approx(0.3)
    assert x.mean == pytest.approx(0.0)
    assert x.std == pytest.approx(np.sqrt((0.01 + 0.09 + 0.04) / 2))
    assert x.rms == pytest.approx(np.sqrt(0.14 / 3))
    # |e| sorted 0.1, 0.2, 0.3: the 99th percentile interpolates 98 % of the way from 0.2 to 0.3.
    assert x.p99_abs == pytest.approx(0.298)
    assert x.within_tolerance == 2 and not x.p99_met
    assert st["Z"].p99_met and st["Z"].max_abs == 0.0
    assert st["Rx"].unit == "deg" and st["Rx"].within_tolerance == 2 and st["Rx"].paper_max == 0.6
    assert st["Rz"].paper_max is None
    assert st["Y"].within_tolerance == 2
    # Each axis has two of three within tolerance, but only the first trial is within on all six.
    assert within_tolerance_all_axes(errors, tolerance_mm=0.25, tolerance_deg=1.0) == 1


def test_no_installs_give_nan_not_a_crash() -> None:
    st = axis_stats([], tolerance_mm=0.5, tolerance_deg=1.0)
    assert len(st) == 6 and all(s.n == 0 and np.isnan(s.p99_abs) and not s.p99_met for s in st)


def test_a_record_without_the_six_figures_is_refused() -> None:
    with pytest.raises(ValueError, match="lacks drz_deg"):
        error_matrix([{k: 0.0 for k in FIELDS[:5]}])
    with pytest.raises(ValueError, match="not finite"):
        error_matrix([_te(0, 0, 0, 0, 0, float("nan"))])


def test_the_p99_difference_interval_covers_the_truth_and_sees_a_real_change() -> None:
    """Against known distributions: two alike samples of 300 give an interval about 0 (in about 95 % of
    draws); a doubled scatter gives one about the true difference of p99|N(0, 1)| = 2.5758 and far from 0."""
    rng = np.random.default_rng(7)
    covered = sum(lo <= 0.0 <= hi for lo, hi in (p99_difference_interval(rng.normal(size=300), rng.normal(size=300), seed=k) for k in range(60)))
    assert covered >= 52  # 95 % of 60 is 57; binomial p(<= 51) is under 1 %
    lo, hi = p99_difference_interval(rng.normal(size=400), 2.0 * rng.normal(size=400))
    assert 0.5 < lo <= 2.5758 <= hi


def test_the_p99_difference_interval_pairs_the_same_postures() -> None:
    """The same cycles in both modes with a small change each: paired, the interval is the change's
    (narrow); the same values unpaired scatter over the whole spread of p99."""
    rng = np.random.default_rng(3)
    before = rng.normal(size=60)
    after = before + 0.05 * rng.normal(size=60)
    lo, hi = p99_difference_interval(before, after)
    ulo, uhi = p99_difference_interval(before, after[:59])  # one cycle fewer: not paired
    assert hi - lo < 0.3 * (uhi - ulo)
    assert np.isnan(p99_difference_interval([0.1], [0.2])[0])


def test_the_p99_of_a_normal_fit_is_the_closed_form_and_scatters_less_than_the_cycles_own() -> None:
    # N(0, 1): P(|e| <= 2.5758) = 0.99; N(3, 1): the lower tail is nil, so q = 3 + 2.3263 (the one-sided 99 %)
    rng = np.random.default_rng(11)
    assert float(normal_p99_abs(rng.normal(size=200_000))) == pytest.approx(2.5758, abs=0.02)
    assert float(normal_p99_abs(3.0 + rng.normal(size=200_000))) == pytest.approx(3.0 + 2.3263, abs=0.02)
    assert float(normal_p99_abs([0.2, 0.2, 0.2])) == pytest.approx(0.2)  # no scatter: the mean's size
    # Many runs of 60 cycles: the normal fit's p99 is about the true one and scatters less between runs; the
    # cycles' own p99 sits between their two largest, low by about a tenth (here 2.33 and 2.58, 0.31 and 0.23).
    samples = rng.normal(size=(400, 60))
    fitted, own = normal_p99_abs(samples, axis=1), np.percentile(np.abs(samples), 99, axis=1)
    assert abs(np.mean(fitted) - 2.5758) < 0.05 and np.mean(own) < 2.45
    assert np.std(fitted) < 0.85 * np.std(own)
    lo, hi = p99_difference_interval(rng.normal(size=400), 2.0 * rng.normal(size=400), normal=True)
    assert 1.5 < lo <= 2.5758 <= hi
