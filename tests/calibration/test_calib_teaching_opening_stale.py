"""A teaching records the opening it was taught for (width, height, corner radius: its install pose holds the glass
made to that size); the recipe's opening edited under the same name makes it stale, naming the field and the command
that teaches it again, and an offline teaching refuses a dataset taken for another size. The opening's nominal place
is not compared (T0 is measured; the cycle measures each car body's place); a teaching recorded before the size was
is not compared either."""

from __future__ import annotations

import copy
import tomllib
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest
from calib_test_support import INPUTS, NOW, VALUES

from cellctl.calibration.calibration_set import CalibrationStore, make_part
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.readiness import check_ready
from cellctl.calibration.taught_shot import refuse_changed_shot, taught_shot
from cellctl.cli import DEFAULT_CONFIG
from cellctl.config import CellConfig, parse_config

LATER = NOW + timedelta(days=1)


def cell(edit: dict[str, Any] | None = None) -> CellConfig:
    """The simulated cell's configuration, the door window's [process.recipes.opening] updated by ``edit``."""
    data = tomllib.loads(Path(DEFAULT_CONFIG).read_text())
    door = data["process"]["recipes"][1]
    assert door["name"] == "door-window"
    door["opening"] |= copy.deepcopy(edit or {})
    return parse_config(data, "sim.toml (test)")


def taught(root: Path, shot: dict[str, Any] | None) -> CalibrationStore:
    """The cell's parts; the side window taught in the first's place, the door window under its name, recording ``shot``."""
    store = CalibrationStore(root)
    for name in ("camera", "hand_eye", "laser"):
        cur = store.current()
        inputs = {dep: cur.part(dep).id for dep in INPUTS[name]} if cur else {}  # type: ignore[union-attr]
        store.commit(name, make_part(name, values=VALUES[name], method="test", when=NOW, valid_days=90.0, inputs=inputs), now=NOW)
    for recipe, slot, own_shot in (("side-window", None, None), ("door-window", "door-window", shot)):
        cal = store.current()
        values = dict(VALUES["teaching"], recipe=recipe, shot=own_shot)
        inputs = {dep: cal.part(dep).id for dep in INPUTS["teaching"]}  # type: ignore[union-attr]
        store.commit("teaching", make_part("teaching", values=values, method="test", when=NOW, valid_days=90.0, inputs=inputs),
                     now=NOW, recipe=slot)  # fmt: skip
        inputs = {"camera": cal.part("camera").id, "teaching": store.current().part("teaching", slot).id}  # type: ignore[union-attr]
        store.commit("pixel_map", make_part("pixel_map", values=VALUES["pixel_map"], method="test", when=NOW, valid_days=90.0,
                                            inputs=inputs), now=NOW, recipe=slot)  # fmt: skip
    return store


def door_problems(store: CalibrationStore, config: CellConfig) -> list[str]:
    return check_ready(store.current(), LATER, recipe="door-window", first_recipe="side-window", config=config)


def test_the_teaching_records_the_opening_it_was_taught_for() -> None:
    shot = taught_shot(cell().for_recipe("door-window"))
    assert (shot["width_mm"], shot["height_mm"], shot["corner_radius_mm"]) == (1200.0, 900.0, 150.0)  # sim.toml's door window
    assert taught_shot(cell({"width_mm": 1300.0}).for_recipe("door-window"))["width_mm"] == 1300.0


def test_a_wider_or_taller_opening_under_the_same_name_makes_its_teaching_stale(tmp_path: Path) -> None:
    store = taught(tmp_path / "taught", taught_shot(cell().for_recipe("door-window")))
    assert door_problems(store, cell()) == []
    where = "([layout.opening], or recipe door-window's [process.recipes.opening])"
    (problem,) = door_problems(store, cell({"width_mm": 1300.0}))
    assert problem == (
        f"teaching of recipe door-window: taught with other settings: the opening's width_mm {where} was 1200 mm, now 1300; "
        "set them back, or teach the recipe again (`cellctl teach --recipe door-window`, then the parts computed with it)"
    )
    (problem,) = door_problems(store, cell({"height_mm": 920.0}))
    assert f"the opening's height_mm {where} was 900 mm, now 920" in problem and "`cellctl teach --recipe door-window`" in problem
    # the side window, whose opening did not change, is not touched
    assert check_ready(store.current(), LATER, recipe="side-window", first_recipe="side-window", config=cell({"width_mm": 1300.0})) == []
    # the opening's nominal place re-measured a few mm off: T0 is measured and each cycle measures the car body's place
    assert door_problems(store, cell({"corner_position_mm": [1703.0, -598.0, 1651.0]})) == []
    # a teaching recorded before the opening's size was: not compared on it, its other settings still are
    older = {k: v for k, v in taught_shot(cell().for_recipe("door-window")).items() if k not in ("width_mm", "height_mm")}
    store = taught(tmp_path / "older", older)
    assert door_problems(store, cell({"width_mm": 1300.0, "height_mm": 920.0})) == []
    (problem,) = door_problems(store, cell({"corner_radius_mm": 120.0}))
    assert "corner_radius_mm" in problem and "was 150 mm, now 120" in problem


def test_an_offline_teaching_refuses_a_dataset_taken_for_another_opening_size() -> None:
    manifest = {"recipe": "door-window", "shot": taught_shot(cell().for_recipe("door-window"))}
    refuse_changed_shot(manifest, cell().for_recipe("door-window"))  # as taken: computed
    with pytest.raises(CalibrationRefused, match=r"the opening's width_mm .* was 1200 mm, now 1300") as err:
        refuse_changed_shot(manifest, cell({"width_mm": 1300.0}).for_recipe("door-window"))
    assert err.value.reason == "settings_changed"
