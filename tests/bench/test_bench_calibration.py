"""cellctl bench calibration on a short laser plan: figures against the twin's truth, bars, exit status."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cellctl.bench.calibration import (
    CalibrationBench,
    SeedResult,
    format_calibration_bench,
    run_calibration_bench,
)
from cellctl.cli import main
from cellctl.config import load_config

CONFIG = Path(__file__).resolve().parents[2] / "config" / "sim.toml"


def _short_plan_config(tmp_path: Path) -> Path:
    text = CONFIG.read_text(encoding="utf-8") + "\n[calibration.procedure.laser]\nn_poses = 160\n"
    path = tmp_path / "sim-short-laser.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_the_cli_prints_each_seed_and_the_bar_and_writes_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = _short_plan_config(tmp_path)
    out_json = tmp_path / "cal.json"
    code = main(["--config", str(cfg), "bench", "calibration", "--seeds", "2", "--seed", "4", "--quiet", "--json", str(out_json)])
    text = capsys.readouterr().out
    data = json.loads(out_json.read_text(encoding="utf-8"))
    assert [s["seed"] for s in data["seeds"]] == [4, 5]
    for s in data["seeds"]:
        assert not s["refused"]
        # The laser r and l are found from 160 readings of the wall (the robot's pose errors on).
        assert 0.0 <= s["figures"]["laser_r_mm"] < 0.3
        assert 0.0 <= s["figures"]["laser_l_deg"] < 0.05
        assert s["figures"]["laser_robot_min"] > 0.5
    summary = data["summary"]["laser_l_deg"]
    assert summary["bar"] == 0.02 and summary["unit"] == "deg"
    assert code == (0 if summary["over_bar"] == 0 and data["summary"]["laser_r_mm"]["over_bar"] == 0 else 1)
    assert "laser l error" in text and "seeds over the bar" in text and "0.02" in text


def test_a_refused_part_or_a_figure_over_its_bar_fails_the_run() -> None:
    ok = SeedResult(1, {"laser_r_mm": 0.1, "laser_l_deg": 0.01})
    over = SeedResult(2, {"laser_r_mm": 0.1, "laser_l_deg": 0.03})
    refused = SeedResult(3, {}, {"laser": "laser refused (plane_too_few_directions): ..."})
    assert CalibrationBench(("laser",), (ok,)).bars_met()
    assert not CalibrationBench(("laser",), (ok, over)).bars_met()
    bench = CalibrationBench(("laser",), (ok, refused))
    assert not bench.bars_met()
    assert "laser refused" in format_calibration_bench(bench)


def test_unknown_parts_are_refused_naming_the_choices() -> None:
    with pytest.raises(ValueError, match="laser, camera, hand_eye"):
        run_calibration_bench(load_config(CONFIG), [1], ["lazer"], progress=False)
