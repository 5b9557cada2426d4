"""A teaching records where and how it read the wall; production refuses a cell that now reads it elsewhere or
otherwise (the taught plane is the cycle's reference: the robot's errors cancel only between like readings)."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from calib_test_support import INPUTS, NOW, VALUES, config

from cellctl.calibration.calibration_set import CalibrationStore, make_part
from cellctl.calibration.readiness import check_ready
from cellctl.commissioning.auto import Needed, parts_needed
from cellctl.commissioning.plans import PlanError, plan_teaching
from cellctl.config import CellConfig

LATER = NOW + timedelta(days=1)


def _with_align(cfg: CellConfig, **update: Any) -> CellConfig:
    process = cfg.process.model_copy(update={"align": cfg.process.align.model_copy(update=update)})
    return cfg.model_copy(update={"process": process})


def _taught(root: Path, wall_read: dict[str, Any] | None) -> CalibrationStore:
    """Camera, hand-eye, laser, nine-point and a teaching of the first recipe that read the wall as ``wall_read``
    (valid for years: the auto-commissioning below asks with the clock's own date)."""
    store = CalibrationStore(root)
    for name in ("camera", "hand_eye", "laser", "teaching", "pixel_map"):
        cur = store.current()
        inputs = {dep: cur.part(dep).id for dep in INPUTS[name]} if cur else {}  # type: ignore[union-attr]
        values = dict(VALUES[name], wall_read=wall_read) if name == "teaching" else VALUES[name]
        store.commit(name, make_part(name, values=values, method="test", when=NOW, valid_days=3650.0, inputs=inputs), now=NOW)
    return store


def test_a_teaching_read_standing_is_refused_for_a_cell_that_now_reads_on_the_move(tmp_path: Path) -> None:
    cfg = config()
    assert cfg.process.align.mode == "stop_and_go"
    store = _taught(tmp_path, {"mode": "stop_and_go", "spots_mm": cfg.process.align.spots_mm})
    assert check_ready(store.current(), LATER, config=cfg) == []
    on_the_move = _with_align(cfg, mode="on_the_fly")
    assert check_ready(store.current(), LATER, config=on_the_move) == [
        "teaching: taught reading the wall standing at process.align.spots_mm (process.align.mode = 'stop_and_go'), "
        "but the cell now reads it along process.align.sweep.path_mm (mode 'on_the_fly'); run `cellctl teach` again, "
        "so the cycle reads the wall where it was taught"
    ]
    # the service's auto-commissioning teaches again (and nothing else)
    years = {"calibration": cfg.calibration.model_copy(update={"max_age_days": 3650.0})}  # the parts' validity, as recorded
    jobs = SimpleNamespace(current_calibration=store.current, config=on_the_move.model_copy(update=years))
    assert parts_needed(jobs) == [Needed("teaching")]  # type: ignore[arg-type]
    as_taught = parts_needed(SimpleNamespace(current_calibration=store.current, config=cfg.model_copy(update=years)))  # type: ignore[arg-type]
    assert [n for n in as_taught if n.recipe is None] == []  # (the second recipe, never taught, comes next)
    # without the configuration (e.g. a set checked on its own) nothing is compared
    assert check_ready(store.current(), LATER) == []


def test_spots_moved_on_the_wall_need_a_new_teaching_a_millimetre_does_not(tmp_path: Path) -> None:
    cfg = config()
    spots = [tuple(s) for s in cfg.process.align.spots_mm]
    store = _taught(tmp_path, {"mode": "stop_and_go", "spots_mm": spots})
    nudged = tuple((x + 0.5, y - 0.5) for x, y in spots)
    assert check_ready(store.current(), LATER, config=_with_align(cfg, spots_mm=nudged)) == []
    moved = tuple([spots[0], (spots[1][0] + 40.0, spots[1][1])] + spots[2:])
    assert check_ready(store.current(), LATER, config=_with_align(cfg, spots_mm=moved)) == [
        "teaching: taught reading the wall at 6 places standing at process.align.spots_mm, but one of them is now "
        "40 mm from where it was taught; run `cellctl teach` again, so the cycle reads the wall where it was taught"
    ]
    two = tuple([(spots[0][0] - 30.0, spots[0][1]), (spots[1][0] + 40.0, spots[1][1])] + spots[2:])
    assert "but 2 of them are now up to 40 mm from where they were taught" in check_ready(
        store.current(), LATER, config=_with_align(cfg, spots_mm=two)
    )[0]
    fewer = _with_align(cfg, spots_mm=tuple(spots[:5]))
    assert "at 6 places standing at process.align.spots_mm, but that setting now names 5;" in check_ready(
        store.current(), LATER, config=fewer
    )[0]
    # the same places in another order read the same wall the same way
    assert check_ready(store.current(), LATER, config=_with_align(cfg, spots_mm=tuple(reversed(spots)))) == []


def test_a_sweep_path_changed_since_teaching_on_the_move_needs_a_new_teaching(tmp_path: Path) -> None:
    cfg = _with_align(config(), mode="on_the_fly")
    sweep = cfg.process.align.sweep
    store = _taught(tmp_path, {"mode": "on_the_fly", "spots_mm": cfg.process.align.wall_spots_mm()})
    assert check_ready(store.current(), LATER, config=cfg) == []
    assert check_ready(store.current(), LATER, config=_with_align(cfg, sweep=sweep.model_copy(update={"speed_mm_s": 500.0}))) == []
    path = [list(c) for c in sweep.path_mm]
    path[-1][1] -= 200.0  # the second leg ends 200 mm earlier: fewer points along it
    shorter = _with_align(cfg, sweep=sweep.model_copy(update={"path_mm": tuple(tuple(c) for c in path)}))
    (problem,) = check_ready(store.current(), LATER, config=shorter)
    assert problem.startswith(f"teaching: taught reading the wall at {len(cfg.process.align.wall_spots_mm())} places "
                              "along process.align.sweep.path_mm, but that setting now names")  # fmt: skip
    # back to reading standing: the mode is named first
    (problem,) = check_ready(store.current(), LATER, config=_with_align(cfg, mode="stop_and_go"))
    assert "(process.align.mode = 'on_the_fly'), but the cell now reads it standing at process.align.spots_mm" in problem


def test_a_teaching_from_before_the_record_is_not_compared(tmp_path: Path) -> None:
    store = _taught(tmp_path, None)
    assert check_ready(store.current(), LATER, config=_with_align(config(), mode="on_the_fly")) == []


def test_a_teaching_for_a_recipe_the_configuration_no_longer_lists_is_named_not_a_crash(tmp_path: Path) -> None:
    cfg = config()
    store = _taught(tmp_path, {"mode": "stop_and_go", "spots_mm": cfg.process.align.spots_mm})
    values = dict(VALUES["teaching"], recipe="door", wall_read={"mode": "stop_and_go", "spots_mm": cfg.process.align.spots_mm})
    inputs = {dep: store.current().part(dep).id for dep in INPUTS["teaching"]}  # type: ignore[union-attr]
    store.commit("teaching", make_part("teaching", values=values, method="test", when=NOW, valid_days=3650.0, inputs=inputs),
                 now=NOW, recipe="door")  # fmt: skip
    assert "door" not in {r.name for r in cfg.process.recipes}
    problems = check_ready(store.current(), LATER, recipe="door", first_recipe=cfg.default_recipe, config=cfg)
    assert "teaching of recipe door: [[process.recipes]] does not list recipe door; add the recipe to the " \
        "configuration or teach one it lists" in problems  # fmt: skip


def test_teaching_places_out_of_reach_name_the_setting_that_puts_them_there(tmp_path: Path) -> None:
    cal = _taught(tmp_path, None).current()
    cfg = config()
    far = ((-6000.0, -60.0), (-4000.0, -60.0), (-4000.0, 1200.0))
    for mode, setting, update in (
        ("stop_and_go", "process.align.spots_mm", {"spots_mm": far}),
        ("on_the_fly", "process.align.sweep.path_mm", {"sweep": cfg.process.align.sweep.model_copy(update={"path_mm": far})}),
    ):
        with pytest.raises(PlanError, match=rf"; move {setting} or the layout's opening"):
            plan_teaching(_with_align(cfg, mode=mode, **update), cal)
