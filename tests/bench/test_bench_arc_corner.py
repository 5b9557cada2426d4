"""The arc detector's benchmark (issue 21): every render accounted for, and scored against its truth."""

from __future__ import annotations

from cellctl.bench.arc_corner import format_arc_corner, run_arc_corner_bench
from cellctl.bench.arc_corner_twin import format_arc_corner_twin, run_arc_corner_twin


def test_the_twin_renders_of_the_door_windows_corner_are_measured_on_the_wall_edge() -> None:
    out = run_arc_corner_twin(6, seed=3)
    assert out["accepted"] + sum(out["refusals"].values()) == 6
    assert out["accepted"] >= 4 and not out["wrong_answers"]
    # The flange's arc is 50-90 px inside the wall's edge: an arc picked wrong would be that far off.
    assert out["centre_error_px"]["max"] < 0.3
    assert out["orientation_answers"] == out["accepted"] and out["orientation_error_deg"]["max"] < 0.05
    assert "150 mm corner" in format_arc_corner_twin(out, 1.0)


def test_the_own_renders_refuse_what_they_cannot_measure_and_never_answer_wrong() -> None:
    out = run_arc_corner_bench(12, seed=2)
    kinds = out["by_kind"]
    assert sum(c.get("accepted", 0) + c.get("refused", 0) for c in kinds.values()) == 12
    assert not out["wrong_answers"] and kinds["radius"].get("accepted", 0) == 0
    assert out["accepted"] >= 4 and out["centre_error_px"]["max"] < 0.3
    assert "wrong answers" in format_arc_corner(out, 1.0)
