"""The simulated cell's glass fits the opening it goes into: a recipe without ``[process.recipes.sim_glass]`` took the
first product's 2000 x 1500 mm glass into its 1200 x 800 mm opening and the twin reported it in tolerance.

Truth: the twin's own car body and glass (``World.in_opening``, the glass outline's signed distance): a glass that
reaches the twin's wall cannot be installed, and the loader refuses it by the recipe's field.
"""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cellctl.config.loader import ConfigError, parse_config
from cellctl.config.sim import GlassConfig, WorldConfig
from cellctl.sim.glass import glass_scene
from cellctl.sim.world import nominal_world

ROOT = Path(__file__).resolve().parents[2]
SIM = tomllib.loads((ROOT / "config" / "sim.toml").read_text(encoding="utf-8"))
HARDWARE = tomllib.loads((ROOT / "config" / "hardware.example.toml").read_text(encoding="utf-8"))
OPENING = {"corner_position_mm": [1700.0, -600.0, 1650.0], "width_mm": 1200.0, "height_mm": 800.0}
SMALL: dict[str, Any] = {
    "id": 3, "name": "small", "opening": OPENING,
    "align": {"spots_mm": [[-1000.0, -60.0], [-300.0, -60.0], [60.0, 200.0], [60.0, 600.0], [-600.0, 860.0], [-1260.0, 400.0]]},
    "inspect": {"flush_spots": [{"glass_mm": [x, 20.0], "wall_mm": [x, -15.0]} for x in (-1000.0, -260.0, -210.0, -160.0, -110.0)]
                + [{"glass_mm": [-20.0, y], "wall_mm": [15.0, y]} for y in (60.0, 110.0, 160.0, 210.0, 700.0)]},
}  # fmt: skip


def _data(base: dict[str, Any], **sim_glass: Any) -> dict[str, Any]:
    """``base`` with the 1200 x 800 mm recipe first, its [process.recipes.sim_glass] ``sim_glass`` (none if empty)."""
    data, recipe = copy.deepcopy(base), copy.deepcopy(SMALL)
    if sim_glass:
        recipe["sim_glass"] = sim_glass
    data["process"]["recipes"] = [recipe, *data["process"]["recipes"]]
    return data


def _glass_on_the_wall(glass: GlassConfig) -> bool:
    """Whether the twin's glass, installed exactly at the 1200 x 800 mm opening (G = T), lies over its wall anywhere."""
    world = nominal_world(WorldConfig(**OPENING))
    scene = glass_scene(glass, world, world.T_B_T)
    x, y = np.meshgrid(np.arange(-2100.0, 50.0, 1.0), np.arange(-50.0, 1600.0, 1.0))
    xy = np.column_stack([x.ravel(), y.ravel()])
    return bool((~world.in_opening(xy) & (scene.distance(xy[:, 0], xy[:, 1]) < 0.0)).any())


def test_a_recipe_without_its_glass_is_refused_as_the_twins_glass_would_lie_on_its_wall() -> None:
    assert _glass_on_the_wall(GlassConfig())  # the truth: the cell's 2000 x 1500 mm glass reaches past this opening
    with pytest.raises(ConfigError) as err:
        parse_config(_data(SIM), "cell.toml")
    text = str(err.value)
    assert "process.recipes[0] (small): sim_glass.width_mm = 2000 is larger than the opening's width_mm = 1200" in text, text
    assert "(the cell's [sim.glass]: this recipe sets no [process.recipes.sim_glass] of its own; give it one)" in text, text


@pytest.mark.parametrize(("extra_mm", "fits"), [(0.0, True), (-40.0, True), (2.0, True), (3.0, False), (6.0, False)])
def test_a_glass_made_for_its_opening_loads_and_one_larger_by_more_than_half_the_gap_is_refused(extra_mm: float, fits: bool) -> None:
    glass = {"width_mm": 1200.0 + extra_mm, "height_mm": 800.0, "corner_in_flange_mm": [600.0, -400.0, 120.0]}
    # the truth: up to the gap (5 mm) larger, the twin's glass stays in the opening; beyond it, it lies on the wall
    assert _glass_on_the_wall(GlassConfig(**glass)) is (extra_mm >= 5.0)
    if fits:
        view = parse_config(_data(SIM, **glass)).for_recipe("small")
        assert (view.sim.glass.width_mm, view.sim.world.width_mm) == (glass["width_mm"], 1200.0)
        return
    with pytest.raises(ConfigError, match=r"process.recipes\[0\] \(small\): sim_glass.width_mm = 120[36] is larger than"):
        parse_config(_data(SIM, **glass), "cell.toml")


def test_the_cells_own_glass_larger_than_its_opening_is_refused_at_its_field() -> None:
    data = copy.deepcopy(SIM)
    data["layout"]["opening"] |= {"height_mm": 1400.0}
    with pytest.raises(ConfigError, match=r"sim.glass.height_mm = 1500 is larger than the opening's height_mm = 1400"):
        parse_config(data, "cell.toml")


def test_a_real_cell_does_not_check_the_twins_glass() -> None:
    config = parse_config(_data(HARDWARE), "hardware.toml")  # no [process.recipes.sim_glass]: no twin
    assert config.for_recipe("small").layout.opening.width_mm == 1200.0
