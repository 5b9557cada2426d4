"""A window whose poses the robot cannot reach is refused at load, named by its recipe and field; the twin's robot is
the truth (it raises ReachError on the pose), and the teaching plan's refusal names a recipe's own settings.

The twin teaches a recipe as the oracle does (its true mountings, the car body at its nominal place: every laser
spot and the shooting pose are moved to), then moves to the install's approach and the install pose as the cycle
does (``cellctl.cell.cycle``: ``T0 @ (0, 0, -approach_mm) @ T_T0_gpos0``). Near where the loader's verdict changes the
twin's true mountings and accuracy move the wrist centre by a few mm, so each boundary is tried 30 mm either side.
"""

from __future__ import annotations

import copy
import tomllib
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cellctl.calibration.calibration_set import CalibrationStore, make_part
from cellctl.commissioning.plans import PlanError, plan_teaching
from cellctl.config import CellConfig, load_config, parse_config
from cellctl.geometry.pose import make_pose
from cellctl.sim.oracle import oracle_calibration
from cellctl.sim.rig import SimRig
from cellctl.sim.robot import ReachError

ROOT = Path(__file__).resolve().parents[2]
SIM = tomllib.loads((ROOT / "config" / "sim.toml").read_text(encoding="utf-8"))
DOOR = 1  # config/sim.toml's door-window, process.recipes[1], its corner at (1700, -600, 1650) mm


def _data(corner: tuple[float, float, float], *, mode: str | None = None) -> dict[str, Any]:
    """config/sim.toml with door-window's opening at ``corner`` (and its own align.mode)."""
    data = copy.deepcopy(SIM)
    recipe = data["process"]["recipes"][DOOR]
    recipe["opening"]["corner_position_mm"] = list(corner)
    if mode is not None:
        recipe["align"]["mode"] = mode
    return data


def _loader_refusal(data: dict[str, Any]) -> str | None:
    try:
        parse_config(data, "sim.toml (test)")
    except ValueError as err:
        return str(err)
    return None


def _twin_view(corner: tuple[float, float, float], *, mode: str | None = None) -> CellConfig:
    """door-window's view with its opening (and the twin's car body) at ``corner``, not validated (the loader may refuse it)."""
    view = load_config(ROOT / "config" / "sim.toml").for_recipe("door-window")
    opening = view.layout.opening.model_copy(update={"corner_position_mm": corner})
    world = view.sim.world.model_copy(update={"corner_position_mm": corner})
    process = view.process
    if mode is not None:
        process = process.model_copy(update={"align": process.align.model_copy(update={"mode": mode})})
    return view.model_copy(update={"layout": view.layout.model_copy(update={"opening": opening}), "process": process,
                                   "sim": view.sim.model_copy(update={"world": world})})  # fmt: skip


def _twin_refusal(view: CellConfig) -> str | None:
    """The twin robot's ReachError while teaching the recipe and moving to its install's approach and pose, or None."""
    rig = SimRig(view.sim, seed=1)
    try:
        taught = oracle_calibration(rig, view, repeats=1).taught
        approach = taught.T0 @ make_pose(np.eye(3), [0.0, 0.0, -view.process.motion.approach_mm]) @ taught.T_T0_gpos0
        rig.cell.execute(approach)
        rig.cell.execute(taught.g_Pos_0)
    except ReachError as err:
        return str(err)
    return None


@pytest.mark.parametrize(
    ("corner", "field"),
    [
        ((3080.0, -600.0, 1650.0), None),  # further from the robot (x): the spot above the opening's far end goes first
        ((3140.0, -600.0, 1650.0), "align.spots_mm[0] [-1300, -60]: the laser's pose that reads it"),
        ((1700.0, -2515.0, 1650.0), None),  # sideways (-y): the shooting pose, beside the arc of the corner nearest it
        ((1700.0, -2575.0, 1650.0), "opening.corner_position_mm = [1700, -2575, 1650]: the shooting pose"),
        ((1700.0, -600.0, 3043.0), None),  # up (z)
        ((1700.0, -600.0, 3103.0), "align.spots_mm[0] [-1300, -60]"),
        ((771.0, -600.0, 1650.0), None),  # towards the robot: the install's approach folds the arm too far
        ((711.0, -600.0, 1650.0), "sim_glass.corner_in_flange_mm = [600, -450, 120]: the install's approach"),
    ],
)
def test_the_loader_refuses_a_recipes_opening_exactly_where_the_twins_robot_cannot_reach(
    corner: tuple[float, float, float], field: str | None
) -> None:
    loader, twin = _loader_refusal(_data(corner)), _twin_refusal(_twin_view(corner))
    assert (loader is None) == (twin is None), (loader, twin)
    if field is None:
        return
    assert f"process.recipes[{DOOR}] (door-window): {field}" in loader, loader  # type: ignore[operator]
    too_close = "too close to the robot" in twin  # type: ignore[operator]
    assert ("too close to the robot" in loader) is too_close and ("out of reach" in loader) is not too_close, loader  # type: ignore[operator]


@pytest.mark.parametrize(("x", "refused"), [(3080.0, False), (3140.0, True)])
def test_a_sweep_out_of_reach_is_refused_by_its_corner(x: float, refused: bool) -> None:
    corner = (x, -600.0, 1650.0)
    loader = _loader_refusal(_data(corner, mode="on_the_fly"))
    twin = _twin_refusal(_twin_view(corner, mode="on_the_fly"))  # teaching reads standing along the sweep's path
    assert (loader is not None) is refused and (twin is not None) is refused, (loader, twin)
    if refused:
        assert f"process.recipes[{DOOR}] (door-window): align.sweep.path_mm[0] [-1300, -60]" in loader, loader  # type: ignore[operator]


FAR = {  # a 2400 x 1200 mm window 1.8 m further out than the cell's, its spots, flush spots and glass its own
    "id": 4, "name": "far", "description": "2400 x 1200 mm",
    "opening": {"corner_position_mm": [3500.0, -1200.0, 1800.0], "width_mm": 2400.0, "height_mm": 1200.0},
    "align": {"spots_mm": [[-1800.0, -60.0], [-600.0, -60.0], [60.0, 300.0], [60.0, 1000.0], [-1200.0, 1260.0], [-2460.0, 600.0]]},
    "inspect": {"flush_spots": [{"glass_mm": [-260.0 + 50 * k, 20.0], "wall_mm": [-260.0 + 50 * k, -15.0]} for k in range(5)]
                + [{"glass_mm": [-20.0, 60.0 + 50 * k], "wall_mm": [15.0, 60.0 + 50 * k]} for k in range(5)]
                + [{"glass_mm": [-20.0, 1000.0], "wall_mm": [15.0, 1000.0]}, {"glass_mm": [-2000.0, 20.0], "wall_mm": [-2000.0, -15.0]}]},
    "sim_glass": {"width_mm": 2400.0, "height_mm": 1200.0, "corner_in_flange_mm": [1200.0, -600.0, 120.0]},
}  # fmt: skip


def test_a_window_out_of_the_robots_reach_is_refused_naming_its_opening() -> None:
    data = copy.deepcopy(SIM)
    data["process"]["recipes"].insert(0, copy.deepcopy(FAR))
    with pytest.raises(ValueError) as refused:
        parse_config(data, "sim.toml (test)")
    text = str(refused.value)
    # its shooting pose: the camera 400 mm before the corner (3500, -1200, 1800), the flange beyond it: |wrist - (0, 0, 780)|
    assert ("process.recipes[0] (far): opening.corner_position_mm = [3500, -1200, 1800]: the shooting pose (the camera "
            "at process.working_distance_mm = 400 before T's point [0, 0]) out of reach: its wrist centre is") in text, text
    assert "beyond the 3100 mm reach" in text and "[layout.robot]" in text and "more of its poses are out of" in text
    # the truth: the twin's robot refuses the recipe's teaching
    view = _twin_view((3500.0, -1200.0, 1800.0))
    assert _twin_refusal(view) is not None


@pytest.mark.parametrize("path", ["config/sim.toml", "config/hardware.example.toml", "src/cellctl/data/sim.toml"])
def test_the_shipped_configurations_load_and_every_recipes_poses_are_in_reach(path: str) -> None:
    config = load_config(ROOT / path)
    if config.mode == "sim":
        for recipe in config.process.recipes:
            assert _twin_refusal(config.for_recipe(recipe.name)) is None, recipe.name


def _mountings_set(root: Path, view: CellConfig) -> Any:
    """A calibration set of camera, hand-eye and laser with the twin's true mountings."""
    now = datetime(2026, 1, 15, 12, 0, tzinfo=timezone.utc)
    store = CalibrationStore(root)
    values = {
        "camera": {"K": view.sim.camera.intrinsics.camera_matrix().tolist(), "dist": [0.0] * 5, "image_size": [2048, 2048]},
        "hand_eye": {"T_H_C": view.sim.camera.hand_eye.T_H_C().tolist()},
        "laser": {"r": view.sim.laser.r.tolist(), "l": view.sim.laser.l.tolist()},
    }
    for name, inputs in (("camera", []), ("laser", []), ("hand_eye", ["camera"])):
        ids = {dep: store.current().part(dep).id for dep in inputs}  # type: ignore[union-attr]
        part = make_part(name, values=values[name], method="test", when=now, valid_days=3650.0, inputs=ids)
        store.commit(name, part, now=now)
    return store.current()


def test_teaching_a_recipe_out_of_reach_names_the_recipes_settings(tmp_path: Path) -> None:
    """The teaching plan (calibrated mountings) of a recipe's job names ``process.recipes[k] (name)``'s settings."""
    view = _twin_view((3500.0, -600.0, 1650.0))  # past the loader (a copy): as if the calibrated mountings differed
    cal = _mountings_set(tmp_path, view)
    with pytest.raises(PlanError) as refused:
        plan_teaching(view, cal, recipe="door-window")
    text = str(refused.value)
    assert text.startswith("teaching: spot 0: target out of reach: its wrist centre is"), text
    assert (f"; move process.recipes[{DOOR}] (door-window): align.spots_mm or opening.corner_position_mm (the recipe's "
            "[process.recipes.align] and [process.recipes.opening]; where it sets none, the cell's "
            "process.align.spots_mm and [layout.opening])") in text, text
    assert _twin_refusal(view) is not None  # the truth: the twin's robot refuses it too
    # a job that names no recipe: the cell's settings, as before
    with pytest.raises(PlanError, match=r"; move process\.align\.spots_mm or the layout's opening$"):
        plan_teaching(view, cal)



@pytest.mark.parametrize("mode", ["stop_and_go", "on_the_fly"])
def test_the_loaders_poses_are_the_planners(mode: str) -> None:
    """The load check's shooting and wall-reading poses are teaching's and the cycle's (their planners' functions)."""
    from cellctl.align import plan_spot_poses
    from cellctl.align.laser_points import sweep_route
    from cellctl.geometry.aiming import nominal_shooting_pose
    from cellctl.config.feature import shot_aim_mm
    from cellctl.config.reach import nominal_poses

    for view in (_twin_view((1700.0, -600.0, 1650.0), mode=mode), load_config(ROOT / "config" / "sim.toml")):
        if mode == "on_the_fly" and view.process.align.mode != mode:
            continue
        lay, ac = view.layout, view.process.align
        T0 = lay.opening.T_B_T_nominal()
        shoot = nominal_shooting_pose(T0, lay.camera_mount.T_H_C(), view.process.working_distance_mm, shot_aim_mm(view))
        places = ac.spots_mm if mode == "stop_and_go" else ac.sweep.path_mm
        wall = list(plan_spot_poses(T0, places, shoot[:3, :3], lay.laser_mount.r, lay.laser_mount.l, ac.laser_standoff_mm))
        if mode == "on_the_fly":
            wall.append(sweep_route(wall, lay.laser_mount.l, ac.sweep.approach_mm, beam_moves=1)[0])  # out along the beam
        poses = nominal_poses(view)
        assert len(poses) == 1 + len(wall) + 2
        for mine, theirs in zip(poses, [shoot, *wall]):
            assert np.allclose(mine.T_B_H, theirs, atol=1e-9), mine.setting
