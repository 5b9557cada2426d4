"""`cellctl align` refuses on one line: a refused alignment exits 1 naming the setting, a bad --seed is a usage error."""

from __future__ import annotations

from pathlib import Path

import pytest
from shared_support import run_cli

from cellctl.config import ConfigError, load_config

SIM = Path(__file__).resolve().parents[2] / "config" / "sim.toml"
# The opening is x in [-2000, 0], y in [0, 1500] of T0 (config/sim.toml): a spot at its middle hits no wall.
SPOT_ON_THE_WALL = "[-1000.0, 1560.0]"
SPOT_IN_THE_OPENING = "[-1000.0, 750.0]"


def test_a_refused_alignment_is_one_line_naming_the_spot_to_move(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = SIM.read_text(encoding="utf-8")
    assert text.count(SPOT_ON_THE_WALL) == 1, "config/sim.toml's process.align.spots_mm changed; update this test"
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text.replace(SPOT_ON_THE_WALL, SPOT_IN_THE_OPENING), encoding="utf-8")
    k = [list(map(float, s)) for s in load_config(SIM).process.align.spots_mm].index([-1000.0, 1560.0])
    with pytest.raises(ConfigError, match=rf"process\.align\.spots_mm\[{k}\] \[-1000, 750\] lies in the opening"):
        load_config(cfg)  # refused at load, before any cycle could find no wall there

    rc, out, err = run_cli(capsys, "--config", str(cfg), "align", "--runs", "1")
    assert rc == 2, err
    assert "Traceback" not in err and f"process.align.spots_mm[{k}]" in err and "move it onto the wall" in err, err
    assert "run 1:" not in out  # nothing ran


def test_a_spot_out_of_the_robots_reach_is_refused_at_load(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = SIM.read_text(encoding="utf-8")
    cfg = tmp_path / "cell.toml"  # 9 m along the car body from the opening: beyond the IRB 7600's 3.1 m reach
    cfg.write_text(text.replace(SPOT_ON_THE_WALL, "[-9000.0, 1560.0]"), encoding="utf-8")
    k = [list(map(float, s)) for s in load_config(SIM).process.align.spots_mm].index([-1000.0, 1560.0])
    said = rf"process\.align\.spots_mm\[{k}\] \[-9000, 1560\]: the laser's pose that reads it .* out of reach"
    with pytest.raises(ConfigError, match=said):
        load_config(cfg)  # refused at load (config.reach), before the robot could refuse it
    rc, out, err = run_cli(capsys, "--config", str(cfg), "align", "--runs", "1")
    assert rc == 2 and "Traceback" not in err and f"process.align.spots_mm[{k}] [-9000, 1560]" in err, err
    assert "run 1:" not in out  # nothing ran


@pytest.mark.parametrize(("seed", "said"), [("-1", "--seed must be ≥ 0 (got -1)"), ("one", "--seed expected a whole number")])
def test_a_bad_seed_is_a_usage_error(seed: str, said: str, capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = run_cli(capsys, "--config", str(SIM), "align", "--seed", seed)
    assert rc == 2 and out == "", out
    assert "Traceback" not in err and said in err, err
