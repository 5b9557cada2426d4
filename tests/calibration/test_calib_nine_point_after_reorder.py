"""After [[process.recipes]] is reordered, a recipe's nine-point job works from that recipe's own teaching and writes
its map beside it: the recipe now listed first does not plan (and map) around the teaching another recipe left in
the first's place, and the one no longer first still finds its teaching there instead of being refused. Truth: the
shooting poses each recipe was taught with (here 400 mm apart in y)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
from calib_test_support import commit_teaching, config, store_with_common_parts
from test_calib_teach import _taught  # the seeded twin commissioned once per test process, shared

from cellctl.calibration.calibration_set import CalibrationSet, CalibrationStore
from cellctl.calibration.compute_recipe import compute_nine_point
from cellctl.calibration.dataset import read_dataset
from cellctl.commissioning.plans import PlanError, plan_nine_point
from cellctl.config import parse_config
from cellctl.config.schema import CellConfig

ROOT = Path(__file__).resolve().parents[2]
SIDE_Y, DOOR_Y = 0.0, -400.0  # y (mm) of each recipe's taught shooting pose C_Pos_0


def _reordered() -> CellConfig:
    """config/sim.toml with the door window listed first."""
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    side, door = data["process"]["recipes"]
    data["process"]["recipes"] = [door, side]
    return parse_config(data)


def _store(root: Path) -> CalibrationStore:
    """The side window taught while it was first (in the first's place), the door window under its name."""
    store = store_with_common_parts(root)
    commit_teaching(store, None, "side-window", SIDE_Y)
    commit_teaching(store, "door-window", "door-window", DOOR_Y)
    return store


def _centre_y(config: CellConfig, cal: CalibrationSet, recipe: str) -> float:
    """y of the middle of the nine planned flange poses (the grid is symmetric about the taught shooting pose)."""
    plan = plan_nine_point(config, cal, recipe=recipe)
    return float(np.mean([p[1, 3] for p in plan.poses]))


def test_each_recipes_nine_point_plan_is_about_its_own_taught_pose_after_a_reorder(tmp_path: Path) -> None:
    config = _reordered()
    cal = _store(tmp_path).current()
    assert cal is not None and config.default_recipe == "door-window"
    assert abs(_centre_y(config, cal, "door-window") - DOOR_Y) < 1e-6  # not the side window's, left in the first's place
    assert abs(_centre_y(config, cal, "side-window") - SIDE_Y) < 1e-6  # found where it was taught, not refused


def test_a_recipe_with_no_teaching_is_refused_with_its_own_command_after_a_reorder(tmp_path: Path) -> None:
    config = _reordered()
    store = store_with_common_parts(tmp_path)
    commit_teaching(store, None, "side-window", SIDE_Y)  # only the side window, in the first's place
    cal = store.current()
    assert cal is not None
    try:
        plan_nine_point(config, cal, recipe="door-window")
    except PlanError as err:
        assert "run `cellctl teach --recipe door-window`" in str(err)  # its own, named
    else:
        raise AssertionError("the door window's nine-point was planned from the side window's teaching")


def test_the_twins_nine_point_map_is_computed_beside_its_teaching_after_a_reorder() -> None:
    """The seeded twin's side window commissioned while first, then listed second: its nine-point dataset computes the
    same map as before the reorder, for the teaching it was taken at (in the first's place), instead of being refused."""
    store, _, _, _ = _taught()
    cal = store.current()
    assert cal is not None and cal.part("pixel_map") is not None
    ds = read_dataset(cal.part("pixel_map").dataset.path, "nine_point")  # type: ignore[union-attr]
    assert ds.manifest.get("recipe") in (None, "side-window")
    before = compute_nine_point(ds, cal, config())
    after = compute_nine_point(ds, cal, _reordered())
    assert before.recipe is None and after.recipe is None  # where the side window's teaching is
    assert after.inputs == before.inputs
    np.testing.assert_allclose(after.values["affine"], before.values["affine"], rtol=0, atol=1e-12)
