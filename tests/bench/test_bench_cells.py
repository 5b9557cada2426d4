"""cellctl bench accuracy --cells: many simulated cells, the loop off and on, a drift, scored against the twin's truth."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import cellctl.bench.cells as cells_mod
from cellctl.bench.accuracy import AccuracyRun, RunSettings, Trial
from cellctl.bench.cells import CellRun, CellsRun, CellsSettings, run_cells
from cellctl.bench.commissioned import Commissioned
from cellctl.bench.drift import DriftSpec, mount_angle_deg
from cellctl.bench.report import format_cells
from cellctl.bench.sources import BenchSettingsError
from cellctl.bench.stats import AXES, axis_stats
from cellctl.cli import main
from cellctl.config import load_config

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "sim.toml"
FIELDS = [a.field for a in AXES]


class _TwinWatch:
    """Records, after every cycle of every run, the twin's own install error and camera mount."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.seen: list[dict[str, Any]] = []
        original = cells_mod.CellHooks.after_cycle
        watch = self

        def after_cycle(hooks: cells_mod.CellHooks, k: int, service: Any, trial: Trial) -> None:
            original(hooks, k, service, trial)
            cell = hooks.twin.cell
            # The hooks object itself, not id(): a finished run's hooks may be freed and its id reused.
            watch.seen.append({"hooks": hooks, "k": k, "error": dict(cell.install_error().as_dict()), "T_H_C": cell.T_H_C.copy()})

        monkeypatch.setattr(cells_mod.CellHooks, "after_cycle", after_cycle)

    def of(self, run: CellRun) -> list[dict[str, Any]]:
        runs = list({id(s["hooks"]): s["hooks"] for s in self.seen}.values())
        for hooks in runs:  # the run's hooks are the ones whose cycles match its trials one to one
            rows = [s for s in self.seen if s["hooks"] is hooks]
            if [r["k"] for r in rows] == [t.index for t in run.run.trials] and all(
                t.true_error is None or t.true_error == pytest.approx(r["error"]) for t, r in zip(run.run.trials, rows)
            ):
                return rows
        raise AssertionError(f"no twin recording matches seed {run.seed} loop {run.loop}")


def _loop_switchable(monkeypatch: pytest.MonkeyPatch, config: Any) -> None:
    """Until this build has the closed loop, let --loop both run twice with the loop as configured."""
    if not cells_mod.spc_available(config):
        monkeypatch.setattr(cells_mod, "spc_available", lambda config: True)
        monkeypatch.setattr(cells_mod, "with_loop", lambda config, enabled: config)


@pytest.mark.timeout(300)
def test_two_cells_loop_both_score_the_twins_truth_and_share_postures(monkeypatch: pytest.MonkeyPatch) -> None:
    config = load_config(CONFIG)
    _loop_switchable(monkeypatch, config)
    watch = _TwinWatch(monkeypatch)
    settings = CellsSettings(cells=2, trials=3, seed=4, loop="both", settle=1, calibration="oracle")
    run = run_cells(config, settings, progress=False)
    assert run.loops == ["off", "on"] and len(run.cells) == 2
    assert [c["off"].seed for c in run.cells] == [4, 5]

    pooled_errors: dict[str, list[dict[str, float]]] = {"off": [], "on": []}
    for cell in run.cells:
        for loop, r in cell.items():
            rows = watch.of(r)
            # Every installed trial's error is the twin's own truth after that cycle.
            E = np.array([[row["error"][f] for f in FIELDS] for row, t in zip(rows, r.run.trials) if t.installed])
            assert len(E) == len(r.errors()) >= 2
            for j, st in enumerate(r.axes()):
                assert st.mean == pytest.approx(np.mean(E[:, j]))
                assert st.std == pytest.approx(np.std(E[:, j], ddof=1))
                assert st.p99_abs == pytest.approx(np.percentile(np.abs(E[:, j]), 99))
            settled = r.settled_mean(1)
            later = [t.true_error for t in r.run.installed if t.index > 1]
            assert settled["X"] == pytest.approx(np.mean([e["dx_mm"] for e in later]))
            pooled_errors[loop] += r.errors()
        # The same car bodies, at the same postures, with the loop off and on.
        off, on = cell["off"].probes, cell["on"].probes
        assert [p["T_B_T"] for p in off] == [p["T_B_T"] for p in on]
        assert off[0]["T_B_T"] != off[1]["T_B_T"]  # a new posture each cycle
    # The cells differ: their postures do.
    assert run.cells[0]["off"].probes[0]["T_B_T"] != run.cells[1]["off"].probes[0]["T_B_T"]
    for loop in ("off", "on"):
        E = np.array([[e[f] for f in FIELDS] for e in pooled_errors[loop]])
        for j, st in enumerate(run.pooled(loop)):
            assert st.n == len(E) and st.p99_abs == pytest.approx(np.percentile(np.abs(E[:, j]), 99))
            assert st.max_abs == pytest.approx(np.max(np.abs(E[:, j])))
    text = format_cells(run)
    assert "pooled over the cells" in text and "loop off" in text and "loop on" in text
    assert "mean error after each cell's first 1 cycles" in text
    json.dumps(run.as_dict())  # everything in --json


@pytest.mark.timeout(300)
def test_the_drift_turns_the_twins_camera_mount_by_the_angle_from_cycle_k(monkeypatch: pytest.MonkeyPatch) -> None:
    config = load_config(CONFIG)
    watch = _TwinWatch(monkeypatch)
    drift = DriftSpec(angle_deg=0.05, at=3, axis="x")
    settings = CellsSettings(cells=1, trials=4, seed=2, loop="off" if cells_mod.spc_available(config) else "on",
                             settle=0, calibration="oracle", drift=drift)  # fmt: skip
    run = run_cells(config, settings, progress=False)
    (r,) = run.runs(run.loops[0])
    rows = watch.of(r)
    start = rows[0]["T_H_C"]
    # Cycles 1 and 2 on the twin's own mount, from cycle 3 on turned 0.05 deg about the camera's x axis.
    assert [mount_angle_deg(row["T_H_C"], start) for row in rows] == pytest.approx([0.0, 0.0, 0.05, 0.05], abs=1e-9)
    assert np.allclose(start, config.sim.camera.hand_eye.T_H_C())
    rel = np.linalg.inv(start) @ rows[2]["T_H_C"]
    a = np.radians(0.05)
    assert np.allclose(rel[:3, :3], [[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]], atol=1e-12)
    assert np.allclose(rel[:3, 3], 0.0)
    assert [p["camera_mount_deg"] for p in r.probes] == pytest.approx([0.0, 0.0, 0.05, 0.05], abs=1e-9)
    # A camera tilted about its x axis looks off along the image's v: the glass lands off in Y, by about
    # the working distance times the angle (400 mm x 0.05 deg = 0.35 mm).
    dy = [t.true_error["dy_mm"] for t in r.run.trials if t.true_error]
    assert np.mean(dy[2:]) - np.mean(dy[:2]) == pytest.approx(400 * np.tan(a), abs=0.15)
    assert "the twin's camera mount turns 0.05 deg about the camera's x axis from cycle 3" in format_cells(run)


def test_drift_spreads_linearly_and_refuses_bad_settings() -> None:
    d = DriftSpec(0.1, at=5, over=4)
    assert [d.angle_at(k) for k in (1, 4, 5, 6, 8, 20)] == pytest.approx([0.0, 0.0, 0.025, 0.05, 0.1, 0.1])
    start = np.eye(4)
    assert mount_angle_deg(d.mount(start, 6), start) == pytest.approx(0.05)
    for bad in ({"angle_deg": 0.1, "at": 0}, {"angle_deg": 0.1, "at": 1, "over": 0}, {"angle_deg": 9.0, "at": 1},
                {"angle_deg": 0.1, "at": 1, "axis": "w"}):  # fmt: skip
        with pytest.raises(BenchSettingsError):
            DriftSpec(**bad)  # type: ignore[arg-type]


def _trial(k: int, dy: float, measured: float | None = None) -> Trial:
    te = {f: 0.0 for f in FIELDS} | {"dy_mm": dy}
    md = None if measured is None else te | {"dy_mm": measured}
    return Trial(k, k, "done", None, te, 0.5, 3, [0.0, 0.0, 0.0], md, None)


def _cell(seed: int, trials: list[Trial], alarms: list[dict[str, Any]]) -> CellRun:
    errors = [t.true_error for t in trials if t.true_error]
    run = AccuracyRun(RunSettings(len(trials), seed), trials, axis_stats(errors, tolerance_mm=0.5, tolerance_deg=1.0),
                      0.5, 1.0, {}, 0.0, 1.0, 0, len(errors))  # fmt: skip
    return CellRun(seed, "on", run, [{"trial": t.index} for t in trials], alarms, {})


def test_alarm_and_tolerance_cycles_settled_means_and_no_inspection_are_reported() -> None:
    alarm = {"cycle": 3, "code": 1313, "name": "SPC_DRIFT", "message": "Y drifting: recalibrate"}
    a = _cell(1, [_trial(1, 0.0), _trial(2, 0.1), _trial(3, 0.3), _trial(4, 0.6), _trial(5, 0.7)], [alarm])
    b = _cell(2, [_trial(k, 0.01) for k in range(1, 6)], [])
    assert a.drift_alarm() == alarm and b.drift_alarm() is None
    assert a.first_out_of_tolerance() == (4, ["Y"]) and b.first_out_of_tolerance() is None
    assert a.settled_mean(2)["Y"] == pytest.approx((0.3 + 0.6 + 0.7) / 3)
    run = CellsRun(CellsSettings(2, 5, 1, settle=2, drift=DriftSpec(0.1, at=2)), ["on"], [{"on": a}, {"on": b}], 0.5, 1.0, 1.0)
    text = format_cells(run)
    assert "no inspection" in text  # no record carries a measured deviation
    row = next(line for line in text.splitlines() if line.strip().startswith("1 loop on") and "cycle 4 (Y)" in line)
    assert row.split()[3] == "3" and row.rstrip().endswith("yes")  # the alarm (cycle 3) came before cycle 4
    assert run.bars()["settled_mean"] is False and run.bars()["inspection_p99"] is None
    # With inspections: measured minus true, pooled p99.
    c = _cell(3, [_trial(1, 0.1, 0.12), _trial(2, 0.2, 0.17)], [])
    n, p99 = CellsRun(CellsSettings(1, 2, 3), ["on"], [{"on": c}], 0.5, 1.0, 1.0).measurement("on")
    assert n == 2 and p99 is not None and p99["Y"] == pytest.approx(np.percentile([0.02, 0.03], 99))


def test_each_cell_is_commissioned_on_its_own_seed_and_its_set_goes_to_every_loop(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    config = load_config(CONFIG)
    _loop_switchable(monkeypatch, config)
    commissioned, ran = [], []

    def commission(base: Any, seed: int, cache: Path, **kw: Any) -> Commissioned:
        commissioned.append((seed, cache))
        return Commissioned(seed, cache / f"seed-{seed}" / "calibration", 1.0, False)

    def run_cell(base: Any, seed: int, trials: int, **kw: Any) -> CellRun:
        ran.append((seed, kw["loop"], kw["calibration_dir"], kw["calibration"]))
        return _cell(seed, [_trial(k, 0.0) for k in range(1, trials + 1)], [])

    monkeypatch.setattr(cells_mod, "commission_cell", commission)
    monkeypatch.setattr(cells_mod, "run_cell", run_cell)
    run_cells(config, CellsSettings(cells=3, trials=2, seed=7, loop="both"), progress=False, calibration_cache=tmp_path)
    assert commissioned == [(7, tmp_path), (8, tmp_path), (9, tmp_path)]
    assert ran == [(s, loop, tmp_path / f"seed-{s}" / "calibration", "data") for s in (7, 8, 9) for loop in ("off", "on")]


def test_cells_cli_refuses_what_does_not_fit(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    base = ["--config", str(CONFIG), "bench", "accuracy", "--calibration", "oracle"]
    assert main([*base, "--cells", "2", "--plots", str(tmp_path)]) == 2
    assert "--plots does not go with --cells" in capsys.readouterr().err
    assert main([*base, "--cells", "2", "--drift-camera-deg", "0.05"]) == 2
    assert "needs both --drift-camera-deg A and --drift-at K" in capsys.readouterr().err
    assert main([*base, "--budget", "parts"]) == 2
    assert "--budget parts compares each cell's calibration" in capsys.readouterr().err
    assert main([*base, "--cells", "2", "--budget", "alone-on"]) == 2
    assert "for many cells use --budget parts" in capsys.readouterr().err


@pytest.mark.timeout(180)
def test_cells_cli_writes_every_figure(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cells.json"
    code = main(["--config", str(CONFIG), "bench", "accuracy", "--cells", "2", "--trials", "2", "--seed", "3",
                 "--calibration", "oracle", "--settle", "1", "--quiet", "--json", str(out)])  # fmt: skip
    report = json.loads(out.read_text())
    assert code in (0, 1) and report["benchmark"] == "accuracy-cells" and report["settings"]["seeds"] == [3, 4]
    loop = report["loops"][0]
    assert [a["axis"] for a in report["pooled"][loop]] == ["X", "Y", "Z", "Rx", "Ry", "Rz"]
    cell = report["cells"][0][loop]
    assert cell["seed"] == 3 and len(cell["trials"]) == 2 and "T_B_T" in cell["trials"][0]
    assert "settled_mean" in cell and "first_out_of_tolerance" in cell and "measurement_error" in report
    assert "per cell: mean / std / p99" in capsys.readouterr().out


def test_a_cached_calibration_set_belongs_to_its_seed_sources_and_configuration() -> None:
    from cellctl.bench.commissioned import _fingerprint
    from cellctl.config import parse_config

    config = load_config(CONFIG)
    fp = _fingerprint(config, 1, ())
    assert fp == _fingerprint(config, 1, ()) and fp != _fingerprint(config, 2, ()) and fp != _fingerprint(config, 1, ("laser_noise",))
    data = config.model_dump(mode="json")
    data["store"]["path"] = "elsewhere.db"  # where the run keeps its store does not matter
    assert _fingerprint(parse_config(data, "test"), 1, ()) == fp
    data["sim"]["laser"]["noise_mm"] = 0.0  # the twin does
    assert _fingerprint(parse_config(data, "test"), 1, ()) != fp
