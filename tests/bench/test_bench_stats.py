"""Per-axis statistics against hand-computed figures, and the budget's attribution."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.bench.stats import AXES, axis_stats, error_matrix, within_tolerance_all_axes

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
