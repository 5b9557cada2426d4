"""Rules of the six measured figures that a mutation run found unguarded: dRz in degrees as the others, and a
flush that marked itself unreliable makes the whole measurement unreliable (it must not feed the quality loop)."""

from __future__ import annotations

import math

import pytest

from cellctl.inspection import FlushResult, measured_deviation


def _flush(unreliable: str | None = None) -> FlushResult:
    return FlushResult(0.1, math.radians(0.02), math.radians(-0.03), (0.1,), 0.0, 0.0, 0.0, unreliable=unreliable)


def test_the_glass_turned_in_plane_by_a_known_angle_reads_that_angle_in_degrees() -> None:
    m = measured_deviation(0.1, -0.2, math.radians(0.3), _flush(), top_gap_mm=5.0, right_gap_mm=5.0)
    d = m.as_dict()
    assert d["drz_deg"] == pytest.approx(0.3, abs=1e-12)
    assert (d["drx_deg"], d["dry_deg"]) == pytest.approx((0.02, -0.03), abs=1e-12)
    assert m.outside(0.5, 0.2) == ["drz_deg=+0.300"]  # a 0.3 deg turn is outside +-0.2 deg, whatever it is in rad


def test_a_flush_missing_a_tilt_setting_spot_makes_the_measurement_unreliable() -> None:
    why = "the flush spots [11], which set the tilt, are missing or left out"
    assert measured_deviation(0.0, 0.0, 0.0, _flush(), top_gap_mm=5.0, right_gap_mm=5.0).reliable
    assert not measured_deviation(0.0, 0.0, 0.0, _flush(why), top_gap_mm=5.0, right_gap_mm=5.0).reliable
