"""Recipes that carry their own window (issue 21): each recipe's sections checked as the tables they replace."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cellctl.config.feature import ShotFeature, arc_view, feature_kind, shot_aim_mm, shot_feature
from cellctl.config.loader import ConfigError, parse_config
from cellctl.config.recipe import RECIPE_SECTIONS, Recipe

ROOT = Path(__file__).resolve().parents[2]
DOOR: dict[str, Any] = {
    "id": 2, "name": "door-window", "description": "1200 x 900 mm door window",
    "opening": {"corner_position_mm": [1700.0, -600.0, 1650.0], "width_mm": 1200.0, "height_mm": 900.0},
    "align": {"spots_mm": [[-900.0, -60.0], [-300.0, -60.0], [60.0, 225.0], [60.0, 675.0], [-600.0, 960.0], [-1260.0, 450.0]]},
    "sim_glass": {"width_mm": 1200.0, "height_mm": 900.0, "corner_in_flange_mm": [600.0, -450.0, 120.0]},
}  # fmt: skip


def _data(*recipes: dict[str, Any]) -> dict[str, Any]:
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    # the cell's flush spots: ones on both windows' glass (sim.toml's door window's), as DOOR sets no inspect
    data["process"]["inspect"]["flush_spots"] = data["process"]["recipes"][1]["inspect"]["flush_spots"]
    data["process"]["inspect"]["sweep_path_mm"] = data["process"]["recipes"][1]["inspect"]["sweep_path_mm"]
    data.setdefault("process", {})["recipes"] = [{"id": 1, "name": "side-window"}, *recipes]
    return data


def test_a_recipe_runs_with_its_own_opening_spots_and_glass_and_the_cells_everything_else() -> None:
    config = parse_config(_data(DOOR))
    door = config.for_recipe("door-window")
    assert (door.layout.opening.width_mm, door.layout.opening.height_mm) == (1200.0, 900.0)
    assert door.layout.opening.corner_position_mm == (1700.0, -600.0, 1650.0)
    assert door.process.align.spots_mm[0] == (-900.0, -60.0)
    # the twin's car body stands at the recipe's opening, and the gripper holds the recipe's glass
    assert (door.sim.world.width_mm, door.sim.world.corner_position_mm) == (1200.0, (1700.0, -600.0, 1650.0))
    assert door.sim.glass.width_mm == 1200.0 and door.sim.glass.corner_in_flange_mm == (600.0, -450.0, 120.0)
    # what the recipe leaves out is the cell's
    assert door.process.align.laser_range_mm == config.process.align.laser_range_mm
    assert door.process.inspect == config.process.inspect and door.vision == config.vision
    assert door.layout.opening.wall_normal == config.layout.opening.wall_normal
    # the cell's own view is untouched; a recipe without sections is the cell's configuration itself
    assert config.layout.opening.width_mm == 2000.0 and config.for_recipe("side-window") is config
    assert config.default_recipe == "side-window"
    # the workpiece frame moved with the opening's corner
    assert np.allclose(door.layout.opening.T_B_T_nominal()[:3, 3], [1700.0, -600.0, 1650.0])


def test_a_bad_recipe_field_refuses_the_config_naming_the_recipe_and_the_field() -> None:
    bad = {**DOOR, "opening": {**DOOR["opening"], "width_mm": -5.0}, "align": {"spotz_mm": [[0.0, 0.0]]}}
    with pytest.raises(ConfigError) as err:
        parse_config(_data(bad), "cell.toml")
    text = str(err.value)
    assert "process.recipes[1] (door-window): opening.width_mm: Input should be greater than 0" in text
    assert "process.recipes[1] (door-window): align.spotz_mm: unknown field" in text
    assert "sim.world" not in text  # the twin's copy of the opening is not a second complaint


def test_a_recipe_can_break_a_rule_that_spans_tables_and_is_told_which() -> None:
    # a 150 mm corner radius makes the arc the feature; aimed at the corner, too little arc is in view
    opening = {**DOOR["opening"], "corner_radius_mm": 150.0}
    bad = {**DOOR, "opening": opening, "vision": {"shot_aim_mm": [0.0, 0.0]}, "sim_glass": DOOR["sim_glass"]}
    with pytest.raises(ConfigError) as err:
        parse_config(_data(bad))
    text = str(err.value)
    assert "process.recipes[1] (door-window)" in text and "corner_radius_mm = 150" in text and "vision.shot_aim_mm" in text


def test_a_large_corner_radius_makes_the_arc_the_feature_with_its_own_aim() -> None:
    config = parse_config(_data({**DOOR, "opening": {**DOOR["opening"], "corner_radius_mm": 150.0}}))
    side, door = config.for_recipe("side-window"), config.for_recipe("door-window")
    assert feature_kind(side) == "corner" and shot_feature(side) == ShotFeature()
    assert feature_kind(door) == "arc"
    feature = shot_feature(door)
    assert feature.point_mm == (-150.0, 150.0)  # the arc's centre in T: left of and below the corner
    assert feature.arc is not None and abs(feature.arc.expected_radius_px - 150.0 * door.layout.camera.fx / 400.0) < 1e-9
    coverage, straight = arc_view(door)  # the default aim: the arc and the top edge's straight run in view
    assert coverage >= 48.0 and straight >= 160.0
    ax, ay = shot_aim_mm(door)
    assert -150.0 < ax < 0.0 and 0.0 < ay < 150.0


def test_unknown_recipe_names_are_refused_with_the_list() -> None:
    config = parse_config(_data(DOOR))
    with pytest.raises(KeyError, match="side-window, door-window"):
        config.for_recipe("boot-lid")


def test_every_recipe_section_lands_in_a_table_of_the_config() -> None:
    config = parse_config(_data())
    for name, path in RECIPE_SECTIONS.items():
        node: Any = config
        for part in path:
            node = getattr(node, part)
        assert node is not None, name
        assert name in Recipe.model_fields


def test_a_copy_with_other_settings_gives_recipe_views_with_those_settings() -> None:
    config = parse_config(_data(DOOR))
    process = config.process.model_copy(update={"align": config.process.align.model_copy(update={"mode": "on_the_fly"})})
    copy = config.model_copy(update={"process": process})
    assert copy.for_recipe("door-window").process.align.mode == "on_the_fly"  # the copy's setting, the recipe's spots
    assert copy.for_recipe("door-window").process.align.spots_mm[0] == (-900.0, -60.0)
    assert config.for_recipe("door-window").process.align.mode == "stop_and_go"  # the original's views are its own



def test_a_copy_at_a_freed_configurations_address_makes_its_own_recipe_views() -> None:
    base = parse_config(_data(DOOR))
    reused = 0
    for _ in range(10):
        first = base.model_copy()
        first.for_recipe("door-window")  # first's own views, made
        process = first.process.model_copy(update={"align": first.process.align.model_copy(update={"mode": "on_the_fly"})})
        moved = first.model_copy(update={"process": process})  # carries first's views until asked
        freed = id(first)
        del first  # CPython hands the freed address (its id()) to the next object of its size: the copy below
        again = moved.model_copy()
        reused += id(again) == freed
        assert again.for_recipe("door-window").process.align.mode == "on_the_fly"
    assert reused  # the case this test is about happened


def test_a_configuration_pickles_compares_by_its_fields_and_a_copy_makes_its_own_recipe_views() -> None:
    import pickle

    config = parse_config(_data(DOOR))
    assert parse_config(_data(DOOR)) == config  # the recipe views do not enter the comparison
    again = pickle.loads(pickle.dumps(config))
    assert again == config and again.for_recipe("door-window").process.align.spots_mm[0] == (-900.0, -60.0)
    assert again.for_recipe("side-window") is again
