"""`cellctl config check` on recipes: it predicts the wall readings of each recipe with its own spots (not the cell's
again), and refuses a recipe whose opening the robot cannot serve, by the recipe's name and field.

The robot time between standing spots is worked independently: each move is a straight line at the travel speed with
the robot's acceleration (a trapezoid, or a triangle on a short move) and the fine point's settling, the flange's
orientation the same at every spot; the fastest order by trying every order of the 6 spots.
"""

from __future__ import annotations

import itertools
import math
import re
import tomllib
from pathlib import Path

import pytest
from config_check_support import ROOT
from config_check_support import refused as _refused
from config_check_support import shipped_copy as _copy
from shared_support import run_cli

SIM = tomllib.loads((ROOT / "config" / "sim.toml").read_text(encoding="utf-8"))


def _robot_s(spots: list[list[float]], order: tuple[int, ...]) -> float:
    """Robot time (s) between the spots in ``order``: config/sim.toml's travel speed, acceleration and settling."""
    v, a = SIM["process"]["motion"]["travel_speed_mm_s"], SIM["layout"]["robot"]["acceleration_mm_s2"]
    settle = SIM["layout"]["robot"]["settle_time_s"]

    def move(p: list[float], q: list[float]) -> float:
        d = math.dist(p, q)
        return (d / v + v / a if d >= v * v / a else 2.0 * math.sqrt(d / a)) + settle

    return sum(move(spots[i], spots[j]) for i, j in zip(order, order[1:]))


def _stop_and_go(block: str) -> tuple[float, float, tuple[int, ...]]:
    m = re.search(r"stop and go: 6 spots, ([\d.]+) s of robot time between them as listed \(([\d.]+) s in the order ([\d, ]+)\)", block)
    assert m is not None, block
    return float(m[1]), float(m[2]), tuple(int(k) for k in m[3].split(", "))


def test_each_recipe_with_its_own_spots_gets_its_own_wall_readings(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(_copy(tmp_path, "sim")))
    assert rc == 0, err
    cell_block = out.split("  wall readings           ", 1)[1].split("\n  wall readings (", 1)[0]
    assert "wall readings (side-window)" not in out  # it reads the cell's spots: the cell's line is its own
    door_block = out.split("  wall readings (door-window)\n", 1)[1].split("\n  secrets", 1)[0]
    for block, spots in ((cell_block, SIM["process"]["align"]["spots_mm"]),
                         (door_block, SIM["process"]["recipes"][1]["align"]["spots_mm"])):  # fmt: skip
        listed, fastest, order = _stop_and_go(block)
        assert listed == pytest.approx(_robot_s(spots, tuple(range(6))), abs=0.05), block
        best = min(_robot_s(spots, o) for o in itertools.permutations(range(6)))  # an order and its reverse tie
        assert sorted(order) == list(range(6)) and _robot_s(spots, order) == pytest.approx(best, abs=1e-9), block
        assert fastest == pytest.approx(best, abs=0.05), block
    assert _stop_and_go(door_block)[0] < _stop_and_go(cell_block)[0] - 2.0  # 9.7 s against 12.0 s: the smaller window's
    assert "this recipe: stop and go (process.align.mode)" in door_block
    assert "this cell: stop and go (process.align.mode)" in cell_block


def test_a_recipe_beyond_the_robots_reach_is_refused_by_its_name(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old = "corner_position_mm = [1700.0, -600.0, 1650.0]"  # door-window's opening, 1.5 m further from the robot
    text = _refused(capsys, _copy(tmp_path, "sim", ((old, "corner_position_mm = [3200.0, -600.0, 1650.0]"),)))
    assert "process.recipes[1] (door-window): opening.corner_position_mm = [3200, -600, 1650]: the shooting pose" in text
    assert "out of reach: its wrist centre is" in text and "beyond the 3100 mm reach" in text


@pytest.mark.parametrize("which", ["sim", "hardware"])
def test_a_cells_opening_beyond_the_robots_reach_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str], which: str) -> None:
    old = "corner_position_mm = [1700.0, -1000.0, 1800.0]"
    text = _refused(capsys, _copy(tmp_path, which, ((old, "corner_position_mm = [3000.0, -1000.0, 1800.0]"),)))
    # (3000, -1000, 1800) is 3323 mm from the reach centre (0, 0, 780), its far corners 3198 mm: within the 3895 mm
    # the laser reads from, but the camera 400 mm before it puts the wrist centre (camera mount and wrist 250 mm behind the flange) past 3100 mm
    assert "layout.opening.corner_position_mm = [3000, -1000, 1800]: the shooting pose" in text and "recipes[" not in text
    assert "out of reach: its wrist centre is" in text and "beyond the 3100 mm reach" in text
