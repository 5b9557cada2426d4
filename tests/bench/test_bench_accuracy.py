"""cellctl bench accuracy end to end on the simulated cell: the report's figures come from the cycle records."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from cellctl.bench.accuracy import RunSettings, run_accuracy
from cellctl.bench.budget import budget_plan
from cellctl.bench.report import format_accuracy
from cellctl.bench.sources import ERROR_SOURCES, BenchSettingsError
from cellctl.bench.stats import AXES
from cellctl.cli import main
from cellctl.config import load_config, parse_config
from cellctl.store import CellStore, CycleState

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "sim.toml"
FIELDS = [a.field for a in AXES]


@pytest.mark.timeout(180)
def test_three_trials_through_the_cli_match_the_store_records(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out_json, plots, work = tmp_path / "acc.json", tmp_path / "plots", tmp_path / "run"
    with_plots = importlib.util.find_spec("matplotlib") is not None  # the optional extra "bench"
    code = main([
        "--config", str(CONFIG), "bench", "accuracy", "--trials", "3", "--seed", "5", "--calibration", "oracle",
        "--json", str(out_json), "--workdir", str(work), "--quiet", *(["--plots", str(plots)] if with_plots else []),
    ])  # fmt: skip
    text = capsys.readouterr().out
    report = json.loads(out_json.read_text())
    assert code in (0, 1) and code == (0 if all(a["p99_met"] for a in report["axes"]) else 1)
    assert report["settings"]["trials"] == 3 and report["settings"]["seed"] == 5
    assert [a["axis"] for a in report["axes"]] == ["X", "Y", "Z", "Rx", "Ry", "Rz"]
    assert report["counts"]["requested"] == 3 and report["counts"]["run"] == 3

    # The trials are the store's cycle records, one to one, with their true errors.
    with CellStore.open(work / "var" / "bench.db") as store:
        records = sorted(store.cycles(limit=10), key=lambda r: r.id)
    assert len(records) == 3
    for trial, rec in zip(report["trials"], records):
        assert trial["cycle_id"] == rec.id
        assert trial["outcome"] == ("done" if rec.state is CycleState.DONE else "failed")
        assert trial["true_error"] == pytest.approx(dict(rec.true_error))
        assert trial["shots"] == (rec.result or {}).get("shots")
    # The per-axis figures are computed from those records.
    done = [r for r in records if r.state is CycleState.DONE]
    assert report["counts"]["installed"] == len(done) >= 2
    E = np.array([[r.true_error[f] for f in FIELDS] for r in done])
    for j, axis in enumerate(report["axes"]):
        assert axis["max_abs"] == pytest.approx(np.max(np.abs(E[:, j])))
        assert axis["mean"] == pytest.approx(np.mean(E[:, j]))
        assert axis["std"] == pytest.approx(np.std(E[:, j], ddof=1))
        assert axis["p99_abs"] == pytest.approx(np.percentile(np.abs(E[:, j]), 99))
        assert axis["n"] == len(done)
    # Every install of the simulated cell is well inside the paper's tolerance.
    assert np.all(np.abs(E[:, :3]) < 0.5) and np.all(np.abs(E[:, 3:]) < 1.0)

    assert "paper max (20 trials)" in text and "p99 target" in text
    for axis in report["axes"]:
        assert f"{axis['max_abs']:8.4f}" in text
    for name in ("fig5_displacement.png", "fig6_rotation.png") if with_plots else ():
        assert (plots / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.timeout(180)
def test_failed_cycles_are_counted_listed_and_the_run_goes_on(tmp_path: Path) -> None:
    data = load_config(CONFIG).model_dump(mode="json")
    data["process"]["limits"]["max_correction_mm"] = 0.5  # every car-body posture needs more than this
    base = parse_config(data, "test")
    run = run_accuracy(base, RunSettings(trials=3, seed=2, calibration="oracle", off=("image_noise",)), progress=False)
    assert [t.outcome for t in run.trials] == ["failed"] * 3
    assert all("the limits are 0.5 mm" in (t.reason or "") for t in run.trials)
    assert run.recoveries == 2  # after each failure but the last, the cell was brought back to Execute
    assert run.counts()["installed"] == 0 and all(a.n == 0 for a in run.axes)
    text = format_accuracy(run)
    assert "cycles that did not install (3)" in text and "trial 2 (cycle 2): failed:" in text
    assert "off: image_noise" in text and "NOT met" in text


def test_cli_refuses_bad_options(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "accuracy", "--off", "laser_nois", "--calibration", "oracle"]) == 2
    assert "unknown error source(s) laser_nois" in capsys.readouterr().err
    assert main(["bench", "accuracy", "--budget", "--off", "laser_noise", "--calibration", "oracle"]) == 2
    assert "--off and --budget" in capsys.readouterr().err
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "x").write_text("x")
    assert main(["bench", "accuracy", "--calibration", "oracle", "--workdir", str(tmp_path / "busy")]) == 2
    assert "is not empty" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["bench", "accuracy", "--trials", "0"])


def test_budget_plans_isolate_each_source() -> None:
    every = set(ERROR_SOURCES)
    on = budget_plan("alone-on", "oracle", data_available=False)
    assert on[0][1:] == (None, tuple(ERROR_SOURCES), "oracle")  # the floor: all off
    isolated = [row[1] for row in on[1:-1]]
    assert "teach_hand_guiding" not in isolated  # acts only through the calibration from data
    assert set(isolated) == every - {"teach_hand_guiding"}
    for label, source, off, cal in on[1:-1]:
        assert set(off) == every - {source} and cal == "oracle"
    assert on[-1][2] == ()
    on_data = budget_plan("alone-on", "data", data_available=True)
    assert all(cal == "data" for _, src, _, cal in on_data if src != "calibration")
    assert ("none, true calibrations", "calibration", tuple(ERROR_SOURCES), "oracle") in on_data
    off_plan = budget_plan("alone-off", "data", data_available=True)
    assert off_plan[0][2] == () and off_plan[-1][1:] == ("calibration", (), "oracle")
    assert [p[2] for p in off_plan[1:-1]] == [(s,) for s in ERROR_SOURCES]
    with pytest.raises(BenchSettingsError, match="--calibration oracle"):
        budget_plan("alone-off", "data", data_available=False)


def test_data_calibration_missing_is_refused_with_the_fix(monkeypatch: pytest.MonkeyPatch) -> None:
    import cellctl.bench.accuracy as accuracy

    monkeypatch.setattr(accuracy, "data_calibration_available", lambda: False)
    with pytest.raises(BenchSettingsError, match="use --calibration oracle"):
        run_accuracy(load_config(CONFIG), RunSettings(trials=1, seed=1, calibration="data"), progress=False)


async def test_data_calibration_runs_use_a_fresh_calibration_set_in_the_workdir(tmp_path: Path) -> None:
    from cellctl.bench.sources import run_config
    from cellctl.service import build_service

    cfg = run_config(load_config(CONFIG), workdir=tmp_path, seed=1, calibration="data")
    service = await build_service(cfg, workdir=tmp_path)
    try:
        source = service.orchestrator.calibration
        assert type(source).__name__ == "CalibrationSetSource"
        assert Path(source.store.root).resolve().is_relative_to(tmp_path.resolve())  # type: ignore[attr-defined]
        assert source.problems()  # nothing calibrated yet: the bench calibrates from simulated data first
    finally:
        await service.stop()


@pytest.mark.timeout(180)
def test_a_mix_of_recipes_reports_each_recipes_figures_from_its_own_records(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out_json, work = tmp_path / "mix.json", tmp_path / "run"
    code = main([
        "--config", str(CONFIG), "bench", "accuracy", "--trials", "8", "--seed", "2", "--calibration", "oracle",
        "--recipes", "mix", "--json", str(out_json), "--workdir", str(work), "--quiet",
    ])  # fmt: skip
    text = capsys.readouterr().out
    report = json.loads(out_json.read_text())
    assert code in (0, 1) and report["settings"]["recipes"] == "mix"
    with CellStore.open(work / "var" / "bench.db") as store:
        records = sorted(store.cycles(limit=20), key=lambda r: r.id)
    by_recipe: dict[str, list] = {}
    for r in records:
        by_recipe.setdefault(r.request.recipe, []).append(r)
    assert set(by_recipe) == {"side-window", "door-window"}  # config/sim.toml's two, both drawn in 8 trials of seed 2
    assert [t["recipe"] for t in report["trials"]] == [r.request.recipe for r in records]
    for name, recs in by_recipe.items():
        done = [r for r in recs if r.state is CycleState.DONE]
        E = np.array([[r.true_error[f] for f in FIELDS] for r in done])
        axes = report["recipes"][name]
        assert [a["n"] for a in axes] == [len(done)] * 6 and len(done) >= 1
        for j, axis in enumerate(axes):
            assert axis["p99_abs"] == pytest.approx(np.percentile(np.abs(E[:, j]), 99))
        assert np.all(np.abs(E[:, :3]) < 0.5) and np.all(np.abs(E[:, 3:]) < 1.0), (name, E)
    assert "per recipe" in text and "door-window" in text and "x)" in text  # each recipe's p99 and its ratio to the first's


@pytest.mark.timeout(180)
def test_the_mix_requested_by_a_line_plc_over_modbus_runs_each_recipe_it_asks_for(tmp_path: Path) -> None:
    from cellctl.bench.accuracy import RunSettings, run_accuracy

    config = load_config(CONFIG)
    settings = RunSettings(6, 4, calibration="oracle", recipes="mix", via="plc")
    run = run_accuracy(config, settings, progress=False, workdir=tmp_path / "run")
    with CellStore.open(tmp_path / "run" / "var" / "bench.db") as store:
        records = sorted(store.cycles(limit=20), key=lambda r: r.id)
    # every cycle came through the cell's Modbus server, keyed by the PLC's cycle_req_id, of the recipe its
    # recipe_id named, and installed within the tolerance
    assert [(r.request.source, r.idempotency_key) for r in records] == [("plc", str(k)) for k in range(1, 7)]
    assert [t.recipe for t in run.trials] == [r.request.recipe for r in records]
    assert {r.request.recipe for r in records} == {"side-window", "door-window"}
    assert all(r.state is CycleState.DONE for r in records) and run.within_tolerance == 6
    assert "requested by a line PLC over Modbus TCP" in format_accuracy(run)
