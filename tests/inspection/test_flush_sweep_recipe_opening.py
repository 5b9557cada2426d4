"""On the move, a recipe's flush sweep is read against the recipe's own opening.

A 1200 x 800 mm recipe that set its own opening and flush spots but kept the cell's ``inspect.sweep_path_mm`` (made for
2000 x 1500 mm: legs at x = -1800 and y = 1300) was accepted; the cycle counted the wall past the small opening's far
sides as glass and measured a good glass 0.82 mm deep (error 1311). Now glass and wall are told apart by the
opening's outline (far sides and rounded corners), such a path is refused at load by the recipe's field, and a path
whose crossings lie on the far edges measures the glass.

Truth: the twin's own car body and glass for the recipe (``World.in_opening``, the glass outline's signed distance),
and its true install error, the glass landing tilted 0.15 deg about x and y.
"""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from shared_support import glass_moved_at_release

from cellctl.bench.accuracy import RunSettings, run_accuracy
from cellctl.config.loader import ConfigError, parse_config
from cellctl.inspection.flush_crossing import surface_at
from cellctl.sim.glass import glass_scene
from cellctl.sim.world import nominal_world

ROOT = Path(__file__).resolve().parents[2]
SIM = tomllib.loads((ROOT / "config" / "sim.toml").read_text(encoding="utf-8"))
NEAR_TOP = [(x, 20.0, x, -15.0) for x in (-260.0, -210.0, -160.0, -110.0, -60.0)]
NEAR_SIDE = [(-20.0, y, 15.0, y) for y in (60.0, 110.0, 160.0, 210.0, 260.0)]
SMALL: dict[str, Any] = {
    "id": 3, "name": "small", "description": "1200 x 800 mm",
    "opening": {"corner_position_mm": [1700.0, -600.0, 1650.0], "width_mm": 1200.0, "height_mm": 800.0},
    "align": {"spots_mm": [[-1000.0, -60.0], [-300.0, -60.0], [60.0, 200.0], [60.0, 600.0], [-600.0, 860.0], [-1260.0, 400.0]],
              "sweep": {"path_mm": [[-1000.0, -100.0], [60.0, -60.0], [60.0, 650.0], [60.0, -60.0]]}},
    "inspect": {"flush_spots": [{"glass_mm": [gx, gy], "wall_mm": [wx, wy]} for gx, gy, wx, wy in
                                [*NEAR_TOP, *NEAR_SIDE, (-20.0, 700.0, 15.0, 700.0), (-1000.0, 20.0, -1000.0, -15.0)]]},
    "sim_glass": {"width_mm": 1200.0, "height_mm": 800.0, "corner_in_flange_mm": [600.0, -400.0, 120.0]},
}  # fmt: skip
# Across the top and the right edge beside the corner, then across the bottom and the left (far) edge: the legs
# (20, 350) -> (-800, 820) and (-600, 775) -> (-1170, 380) run over the glass from one side to the other.
FAR_EDGES = [[-350.0, -20.0], [-150.0, 25.0], [-25.0, 150.0], [20.0, 350.0], [-800.0, 820.0], [-600.0, 775.0],
             [-1170.0, 380.0], [-1225.0, 580.0]]  # fmt: skip


def _data(recipe: dict[str, Any]) -> dict[str, Any]:
    """config/sim.toml on the move with ``recipe`` first (the benches run the first recipe)."""
    data = copy.deepcopy(SIM)
    data["process"]["align"]["mode"] = "on_the_fly"
    data["process"]["recipes"] = [recipe, *data["process"]["recipes"]]
    return data


def _small(sweep_path_mm: list[list[float]] | None) -> dict[str, Any]:
    recipe = copy.deepcopy(SMALL)
    if sweep_path_mm is not None:
        recipe["inspect"]["sweep_path_mm"] = sweep_path_mm
    return recipe


def _twin(view: Any) -> tuple[Any, Any]:
    """The twin's car body for ``view`` at its nominal place, and its glass installed there (G = T)."""
    world = nominal_world(view.sim.world)
    return world, glass_scene(view.sim.glass, world, world.T_B_T)


@pytest.mark.parametrize("recipe", ["small", "door-window"])
def test_glass_and_wall_are_told_apart_where_the_twin_has_them_far_sides_and_arcs_included(recipe: str) -> None:
    view = parse_config(_data(_small(FAR_EDGES))).for_recipe(recipe)
    world, glass = _twin(view)
    insp, gap = view.process.inspect, view.sim.glass.edge_gap_mm
    o = view.layout.opening
    x, y = np.meshgrid(np.arange(-o.width_mm - 60.0, 60.0, 2.5), np.arange(-60.0, o.height_mm + 60.0, 2.5))
    xy = np.column_stack([x.ravel(), y.ravel()])
    s = surface_at(xy, insp.nominal_gap_mm, insp.sweep_margin_mm, view.process.opening)
    to_glass = glass.distance(xy[:, 0], xy[:, 1])  # < 0 inside the glass's edge
    to_opening = to_glass - gap  # the glass is the opening inset by the gap: < 0 inside the opening
    m = insp.sweep_margin_mm
    assert np.all(to_glass[s > 0] < -m + 1e-9), "a glass reading off the twin's glass (or within the margin of its edge)"
    assert not world.in_opening(xy[s < 0]).any() and np.all(to_opening[s < 0] > m - 1e-9), "a wall reading in the opening"
    assert np.all(s[to_glass < -m - 1e-6] > 0) and np.all(s[to_opening > m + 1e-6] < 0), "a reading left out beyond the margins"
    beyond = (xy[:, 0] < -o.width_mm - m - 1e-6) | (xy[:, 1] > o.height_mm + m + 1e-6)
    assert beyond.any() and np.all(s[beyond] < 0)  # past the far sides: the wall, as the twin has it


def test_a_recipe_keeping_the_cells_sweep_for_another_opening_is_refused_by_its_field() -> None:
    with pytest.raises(ConfigError) as err:
        parse_config(_data(_small(None)), "cell.toml")
    text = str(err.value)
    assert "process.recipes[0] (small): inspect.sweep_path_mm: it crosses an edge on 2 legs" in text, text
    assert "beyond the far sides of this opening (1200 x 800 mm" in text, text
    assert "this recipe's [process.recipes.inspect] sets no sweep_path_mm; give it its own" in text, text
    # the truth: the cell's path has its far legs' glass ends on the twin's wall around this opening
    view = parse_config(_data(_small(FAR_EDGES))).for_recipe("small")
    world, glass = _twin(view)
    cells = np.array(parse_config(_data(_small(FAR_EDGES))).process.inspect.sweep_path_mm)
    far = cells[(cells[:, 0] < -1200.0) | (cells[:, 1] > 800.0)]
    assert len(far) == 4 and not world.in_opening(far).any() and np.all(glass.distance(far[:, 0], far[:, 1]) > 0.0)


def test_the_flush_read_across_the_far_edges_of_a_recipes_opening_is_the_twins_true_install(tmp_path: Path) -> None:
    # Before, the path was refused: its far crossings' wall ends counted as glass (x < 0, y > 0 was glass).
    config = parse_config(_data(_small(FAR_EDGES)))
    tilt = np.eye(4)
    ax = ay = np.radians(0.15)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(ax), -np.sin(ax)], [0.0, np.sin(ax), np.cos(ax)]])
    ry = np.array([[np.cos(ay), 0.0, np.sin(ay)], [0.0, 1.0, 0.0], [-np.sin(ay), 0.0, np.cos(ay)]])
    tilt[:3, :3] = ry @ rx
    run = run_accuracy(config, RunSettings(trials=2, seed=3, calibration="oracle", time_scale=0.0), progress=False,
                       workdir=tmp_path / "w", hooks=glass_moved_at_release(tilt))  # fmt: skip
    for t in run.trials:
        assert t.recipe == "small" and t.outcome == "done", t.reason
        e, measured = t.true_error or {}, t.measured_deviation
        assert measured is not None and abs(e["drx_deg"]) > 0.05 and abs(e["dry_deg"]) > 0.05, (e, measured)
        for k, tol in (("dz_mm", 0.03), ("drx_deg", 0.01), ("dry_deg", 0.01)):
            assert abs(measured[k] - e[k]) < tol, (k, measured[k], e[k])
