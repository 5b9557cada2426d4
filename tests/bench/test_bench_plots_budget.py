"""Plots of Figs. 5 and 6 and the budget's attribution, on runs built from known errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.bench.accuracy import AccuracyRun, RunSettings, Trial
from cellctl.bench.budget import Budget, BudgetRow
from cellctl.bench.report import format_budget
from cellctl.bench.stats import AXES, axis_stats

PNG = b"\x89PNG\r\n\x1a\n"


def _run(errors: list[tuple[float, ...]], *, failed: int = 0, off: tuple[str, ...] = ()) -> AccuracyRun:
    trials = [
        Trial(k + 1, k + 1, "done", None, {a.field: e[j] for j, a in enumerate(AXES)}, 0.5, 3, [0.0, 0.0, 0.0])
        for k, e in enumerate(errors)
    ]
    trials += [Trial(len(trials) + k + 1, None, "failed", "corner not found", None, None, None, None) for k in range(failed)]
    installed = [t.true_error for t in trials if t.true_error]
    return AccuracyRun(
        settings=RunSettings(len(trials), 1, off, "oracle"),
        trials=trials,
        axes=axis_stats(installed, tolerance_mm=0.5, tolerance_deg=1.0),
        tolerance_mm=0.5,
        tolerance_deg=1.0,
        calibration_summary={},
        calibration_s=0.0,
        wall_s=1.0,
        recoveries=failed,
        within_tolerance=len(installed),
    )


def test_figures_5_and_6_are_written(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib", reason="the plots are the optional extra 'bench'")
    from cellctl.bench.plots import write_accuracy_plots

    run = _run([(0.1, -0.05, 0.02, 0.004, -0.002, 0.001), (-0.08, 0.12, -0.03, -0.003, 0.001, 0.0)], failed=1)
    paths = write_accuracy_plots(run, tmp_path / "p")
    assert [p.name for p in paths] == ["fig5_displacement.png", "fig6_rotation.png"]
    assert all(p.read_bytes()[:8] == PNG and p.stat().st_size > 10_000 for p in paths)


def test_budget_names_the_source_that_adds_most_per_axis() -> None:
    floor = _run([(0.01, 0.01, 0.01, 0.001, 0.001, 0.001), (-0.01, -0.01, -0.01, -0.001, -0.001, -0.001)])
    # robot_accuracy adds mostly to X and Rz, image_noise mostly to Y; nothing adds to Z beyond the floor.
    robot = _run([(0.05, 0.02, 0.01, 0.001, 0.001, 0.02), (-0.05, -0.02, -0.01, -0.001, -0.001, -0.02)])
    image = _run([(0.02, 0.06, 0.01, 0.001, 0.001, 0.001), (-0.02, -0.06, -0.01, -0.001, -0.001, -0.001)])
    rows = [
        BudgetRow("none (floor)", None, ("robot_accuracy", "image_noise"), "oracle", floor),
        BudgetRow("robot_accuracy alone", "robot_accuracy", ("image_noise",), "oracle", robot),
        BudgetRow("image_noise alone", "image_noise", ("robot_accuracy",), "oracle", image),
    ]
    budget = Budget("alone-on", 2, 1, rows, rows[0])
    dom = budget.dominant()
    assert dom["X"] == "robot_accuracy" and dom["Rz"] == "robot_accuracy" and dom["Y"] == "image_noise"
    assert dom["Z"] is None and dom["Rx"] is None
    shares = budget.shares()
    assert shares["robot_accuracy"]["X"] == pytest.approx(0.04)  # p99 0.05 with it, 0.01 without
    text = format_budget(budget)
    assert "dominant source per axis" in text and "bias and spread" in text and "what would reduce" in text and "robot_accuracy:" in text

    # Alone off: the source whose removal takes the most away dominates.
    everything = robot
    rows_off = [
        BudgetRow("all on", None, (), "oracle", everything),
        BudgetRow("all but robot_accuracy", "robot_accuracy", ("robot_accuracy",), "oracle", floor),
        BudgetRow("all but image_noise", "image_noise", ("image_noise",), "oracle", everything),
    ]
    assert Budget("alone-off", 2, 1, rows_off, rows_off[0]).dominant()["X"] == "robot_accuracy"


def test_budget_plot_is_written(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib", reason="the plots are the optional extra 'bench'")
    from cellctl.bench.plots import write_budget_plot

    r = _run([(0.01, 0.02, 0.03, 0.001, 0.002, 0.003)])
    rows = [BudgetRow("floor", None, (), "oracle", r), BudgetRow("x alone", "laser_noise", (), "oracle", r)]
    path = write_budget_plot(Budget("alone-on", 1, 1, rows, rows[0]), tmp_path)
    assert path.read_bytes()[:8] == PNG
