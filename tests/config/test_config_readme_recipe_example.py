"""README's recipe example ("Several window types: recipes"), copied as printed into config/sim.toml in place of its
door-window, loads: stop and go and on the move, its spots, flush sweep and glass fitting its own opening.

Truth for the fit: the twin's own car body and glass for that recipe (the glass inside the opening, every flush spot's
glass reading on the glass and its wall reading on the wall, the flush sweep's legs from the glass to the wall).
"""

from __future__ import annotations

import copy
import re
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cellctl.config.loader import parse_config
from cellctl.sim.glass import glass_scene
from cellctl.sim.world import nominal_world

ROOT = Path(__file__).resolve().parents[2]


def _readme_recipe() -> dict[str, Any]:
    """The ```toml block of README's recipe section, parsed: its one [[process.recipes]]."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("### Several window types: recipes"):]
    section = section[: section.index("\n## ")]
    blocks = re.findall(r"```toml\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "README's recipe section has one toml example"
    (recipe,) = tomllib.loads(blocks[0])["process"]["recipes"]
    return recipe


def _sim_with_the_example(mode: str) -> dict[str, Any]:
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text(encoding="utf-8"))
    recipes = data["process"]["recipes"]
    k = next(i for i, r in enumerate(recipes) if r["name"] == "door-window")
    recipes[k] = copy.deepcopy(_readme_recipe())
    data["process"]["align"]["mode"] = mode
    return data


@pytest.mark.parametrize("mode", ["stop_and_go", "on_the_fly"])
def test_the_readme_recipe_loads_in_place_of_sim_tomls_door_window(mode: str) -> None:
    example = _readme_recipe()
    assert {"opening", "align", "inspect", "sim_glass"} <= set(example)  # all a recipe with its own opening needs
    view = parse_config(_sim_with_the_example(mode), "sim.toml with README's recipe").for_recipe(example["name"])
    world = nominal_world(view.sim.world)
    glass = glass_scene(view.sim.glass, world, world.T_B_T)
    o = view.layout.opening
    assert (o.width_mm, o.height_mm) == (example["opening"]["width_mm"], example["opening"]["height_mm"])
    # the twin's glass lies in the twin's opening
    x, y = np.meshgrid(np.arange(-o.width_mm - 20.0, 20.0, 2.0), np.arange(-20.0, o.height_mm + 20.0, 2.0))
    xy = np.column_stack([x.ravel(), y.ravel()])
    assert not (~world.in_opening(xy) & (glass.distance(xy[:, 0], xy[:, 1]) < 0.0)).any()
    for spot in view.process.inspect.flush_spots:  # each reading where the twin has its surface
        assert glass.distance(*spot.glass_mm) < 0.0 and not world.in_opening(spot.wall_mm)[0], spot
    path = np.array(view.process.inspect.sweep_path_mm)
    on_glass, on_wall = glass.distance(path[:, 0], path[:, 1]) < 0.0, ~world.in_opening(path)
    assert np.all(on_glass ^ on_wall) and np.count_nonzero(on_glass[1:] != on_glass[:-1]) >= 3  # three legs cross an edge
