"""A non-finite measured figure never marks the part OK (the SPC loop excludes the same result as NOT_FINITE)."""

from __future__ import annotations

import math

import pytest

from cellctl.inspection import FlushResult, measured_deviation

FIGURES = ["dx_mm", "dy_mm", "dz_mm", "drx_deg", "dry_deg", "drz_deg"]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("name", FIGURES)
def test_a_non_finite_figure_is_outside_the_tolerance(name: str, bad: float) -> None:
    flush = FlushResult(bad if name == "dz_mm" else 0.0, 0.0, 0.0, (0.0,), 0.0, 0.0, 0.0)
    m = measured_deviation(
        bad if name == "dx_mm" else 0.0, bad if name == "dy_mm" else 0.0, bad if name == "drz_deg" else 0.0, flush,
        top_gap_mm=5.0, right_gap_mm=5.0,
    )
    if name in ("drx_deg", "dry_deg"):
        m = measured_deviation(0.0, 0.0, 0.0, FlushResult(0.0, bad if name == "drx_deg" else 0.0,
                               bad if name == "dry_deg" else 0.0, (0.0,), 0.0, 0.0, 0.0), top_gap_mm=5.0, right_gap_mm=5.0)  # fmt: skip
    out = m.outside(0.5, 1.0)
    assert [o.split("=")[0] for o in out] == [name]


def test_finite_figures_at_the_limit_stay_inside() -> None:
    m = measured_deviation(0.5, -0.5, 0.0, FlushResult(0.5, 0.0, 0.0, (0.0,), 0.0, 0.0, 0.0), top_gap_mm=5.0, right_gap_mm=5.0)
    assert m.outside(0.5, 1.0) == []
    assert m.outside(0.4999, 1.0) == ["dx_mm=+0.500", "dy_mm=-0.500", "dz_mm=+0.500"]
