"""What a recipe may set, said as such; and the spots the laser reads fit each recipe's opening.

A flush spot's glass reading must fall on the glass (the opening inset by the nominal gap, with its corner arc),
its wall reading on the wall, and the cell's alignment spots a recipe keeps on the wall around its own opening. The geometry is checked against the twin's own
glass: the twin's simulated laser, cast at a spot, says whether it hits the glass.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest

from cellctl.config.loader import ConfigError, parse_config
from cellctl.config.recipe import RECIPE_SECTIONS

ROOT = Path(__file__).resolve().parents[2]


def _sim() -> dict[str, Any]:
    return tomllib.loads((ROOT / "config" / "sim.toml").read_text())


def _refusal(data: dict[str, Any]) -> str:
    with pytest.raises(ConfigError) as err:
        parse_config(data, "cell.toml")
    return str(err.value)


@pytest.mark.parametrize("section,home", [("tolerance", "[process.tolerance]"), ("camera", "[layout.camera]"), ("spc", "[process.spc]")])
def test_a_section_of_the_cell_set_in_a_recipe_is_named_with_where_it_belongs(section: str, home: str) -> None:
    data = _sim()
    data["process"]["recipes"][1][section] = {"position_mm": 0.3}
    text = _refusal(data)
    assert f"process.recipes.1.{section}: a recipe may set only" in text
    assert all(f"[process.recipes.{name}]" in text for name in RECIPE_SECTIONS)
    assert f"it is the cell's, for every recipe: set it in {home}" in text and "spelling" not in text


def test_a_misspelt_recipe_key_is_still_told_to_check_its_spelling() -> None:
    data = _sim()
    data["process"]["recipes"][1]["opning"] = {"width_mm": 1200.0}
    assert "process.recipes.1.opning: a recipe may set only" in (text := _refusal(data)) and "check its spelling" in text


def test_the_shipped_configurations_fit_their_spots() -> None:
    for path in (ROOT / "config").glob("*.toml"):
        config = parse_config(tomllib.loads(path.read_text()), path.name)
        for recipe in config.process.recipes:
            config.for_recipe(recipe.name)


def test_a_recipe_with_its_own_opening_and_the_cells_flush_spots_is_refused_naming_the_spot_and_the_fix() -> None:
    data = _sim()
    del data["process"]["recipes"][1]["inspect"]  # the door window keeps its 1200 x 900 opening, not its spots
    text = _refusal(data)
    assert "process.recipes[1] (door-window): inspect.flush_spots[4].glass_mm [-60, 20] is beyond the corner arc" in text
    assert _twin(_sim(), "door-window")[1].distance(-60.0, 20.0) > 0.0  # the twin's door glass is not there
    assert "this recipe sets no [process.recipes.inspect] of its own; give it one" in text


def _twin(data: dict[str, Any], recipe: str) -> tuple[Any, Any]:
    """The twin's car body at its nominal place for ``recipe``, and its glass installed there (G = T)."""
    from cellctl.sim.glass import glass_scene
    from cellctl.sim.world import nominal_world

    view = parse_config(data).for_recipe(recipe)
    world = nominal_world(view.sim.world)
    return world, glass_scene(view.sim.glass, world, world.T_B_T)


def test_every_spot_the_rule_accepts_in_sim_toml_is_where_the_twin_has_glass_or_wall() -> None:
    data = _sim()
    config = parse_config(data)
    for recipe in config.process.recipes:
        world, glass = _twin(data, recipe.name)
        view = config.for_recipe(recipe.name)
        for spot in view.process.inspect.flush_spots:
            assert glass.distance(*spot.glass_mm) < 0.0 and not world.in_opening(spot.wall_mm)[0], (recipe.name, spot)
        assert not world.in_opening(view.process.align.spots_mm).any(), recipe.name


@pytest.mark.parametrize("where,spot,message", [
    ("glass", {"glass_mm": [-20.0, 1200.0], "wall_mm": [15.0, 1200.0]}, "flush_spots[11].glass_mm [-20, 1200] is off the glass"),
    ("wall", {"glass_mm": [-20.0, 600.0], "wall_mm": [-60.0, 600.0]}, "flush_spots[11].wall_mm [-60, 600] lies in the opening"),
])  # fmt: skip
def test_a_recipes_own_spot_off_its_glass_or_wall_is_refused(where: str, spot: dict[str, Any], message: str) -> None:
    data = _sim()
    data["process"]["recipes"][1]["inspect"]["flush_spots"][11] = spot
    text = _refusal(data)
    assert f"process.recipes[1] (door-window): inspect.{message}" in text and "of its own" not in text
    world, glass = _twin(_sim(), "door-window")  # the twin agrees: no glass, or no wall, there
    assert glass.distance(*spot["glass_mm"]) > 0.0 if where == "glass" else world.in_opening(spot["wall_mm"])[0]


def test_the_cells_alignment_spots_inside_a_recipes_larger_opening_are_refused() -> None:
    data = _sim()
    del data["process"]["recipes"][1]["align"]  # the door window's opening made larger than the cell's, its spots the cell's
    data["process"]["recipes"][1]["opening"] |= {"width_mm": 2200.0, "height_mm": 1700.0}
    text = _refusal(data)
    assert "process.recipes[1] (door-window): align.spots_mm[4] [-1000, 1560] lies in the opening" in text
    assert "this recipe sets no [process.recipes.align] of its own; give it one" in text
    world = _twin(_sim(), "side-window")[0]
    assert not world.in_opening([-1000.0, 1560.0])[0]  # on the cell's own opening's wall
    big = world.__class__(world.T_B_T, 2200.0, 1700.0, 150.0)
    assert big.in_opening([-1000.0, 1560.0])[0]  # the twin's larger opening has no wall there
