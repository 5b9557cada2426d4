"""A recipe's own parts are looked up by its name, whatever its place in [[process.recipes]]; the parts kept in
the first recipe's place count as a recipe's only when their teaching names it (or names none and it is first);
and a recipe whose teaching names another recipe is refused up front with the command that teaches it."""

from __future__ import annotations

import sys
import tomllib
from datetime import timedelta
from pathlib import Path
from typing import Any


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "calibration"))
from calib_test_support import NOW, store_with_common_parts  # noqa: E402
from calib_test_support import commit_teaching as _teach  # noqa: E402

from cellctl.calibration.calibration_set import CalibrationStore, parts_of  # noqa: E402
from cellctl.calibration.readiness import check_ready  # noqa: E402
from cellctl.calibration.source import CalibrationSetSource  # noqa: E402
from cellctl.config import parse_config  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
LATER = NOW + timedelta(days=1)


def _cell(root: Path) -> CalibrationStore:
    """The cell's parts; the side window's teaching in the first's place, the door window's under its name."""
    store = store_with_common_parts(root)
    _teach(store, None, "side-window", 0.0)
    _teach(store, "door-window", "door-window", -400.0)
    return store


def test_each_recipe_finds_its_own_teaching_by_name_in_any_order(tmp_path: Path) -> None:
    cal = _cell(tmp_path).current()
    assert cal is not None
    for first in ("side-window", "door-window", "side-glass"):
        assert parts_of(cal, "door-window", first) == "door-window"
    assert parts_of(cal, "side-window", "side-window") is None  # in the first's place, taught for it
    assert parts_of(cal, "side-window", "door-window") is None  # no longer first: still its own
    assert parts_of(cal, "side-glass", "side-glass") == "side-glass"  # renamed: the side window's is not its
    assert check_ready(cal, LATER, recipe="door-window", first_recipe="door-window") == []
    assert cal.taught(parts_of(cal, "door-window", "door-window")).T0[1, 3] == cal.taught().T0[1, 3] - 400.0
    assert check_ready(cal, LATER, recipe="side-glass", first_recipe="side-glass") == [
        "teaching of recipe side-glass: missing; run `cellctl teach --recipe side-glass`",
        "pixel_map of recipe side-glass: missing; run `cellctl calibrate nine-point --recipe side-glass`",
    ]  # in the order they are commissioned


def test_a_newer_teaching_in_the_first_place_for_that_recipe_is_the_one_read(tmp_path: Path) -> None:
    store = _cell(tmp_path)
    _teach(store, None, "door-window", -380.0, when=NOW + timedelta(hours=1))  # taught again, now that it is first
    cal = store.current()
    assert cal is not None and parts_of(cal, "door-window", "door-window") is None
    assert cal.taught(parts_of(cal, "door-window", "door-window")).T0[1, 3] == -380.0
    assert "door-window" not in cal.recipes  # its earlier one under its name is gone with it: one teaching a recipe


def _source(store: CalibrationStore, recipes: list[dict[str, Any]]) -> CalibrationSetSource:
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data["process"]["recipes"] = recipes
    return CalibrationSetSource(store, parse_config(data))


def test_a_teaching_that_names_another_recipe_refuses_its_cycles_with_the_command(tmp_path: Path) -> None:
    store = _cell(tmp_path)
    side, door = tomllib.loads((ROOT / "config" / "sim.toml").read_text())["process"]["recipes"]
    _teach(store, "door-window", "side-window", -400.0)  # stored under the door window's name, taught for the side window
    source = _source(store, [side, door])
    assert source.untaught("door-window") == (
        "recipe door-window is not taught: the teaching it finds was taught for recipe side-window; "
        "run `cellctl teach --recipe door-window`"
    )
    assert source.untaught("side-window") is None
    renamed = _source(store, [{**side, "name": "side-glass"}, door])
    assert renamed.untaught("side-glass") == "recipe side-glass is not taught: its teaching is missing; run `cellctl teach --recipe side-glass`"
