"""Each recipe's own teaching and nine-point map in the calibration set (issue 21); the cell's parts stay shared."""

from __future__ import annotations

import json
from datetime import timedelta
from pathlib import Path

from calib_test_support import INPUTS, NOW, VALUES, commit_teaching

from cellctl.calibration.calibration_set import CalibrationStore, load_calibration_set, make_part
from cellctl.calibration.readiness import check_ready


def _cell(root: Path) -> CalibrationStore:
    """Camera, hand-eye, laser, and the first recipe's teaching and nine-point map."""
    store = CalibrationStore(root)
    for name in ("camera", "hand_eye", "laser", "teaching", "pixel_map"):
        cur = store.current()
        inputs = {dep: cur.part(dep).id for dep in INPUTS[name]} if cur else {}  # type: ignore[union-attr]
        store.commit(name, make_part(name, values=VALUES[name], method="test", when=NOW, valid_days=90.0, inputs=inputs), now=NOW)
    return store


def _teach(store: CalibrationStore, recipe: str, shift_mm: float, *, taught_for: str | None = None) -> None:
    commit_teaching(store, recipe, taught_for or recipe, shift_mm)


def test_a_second_recipe_is_taught_on_its_own_and_the_first_keeps_its_teaching(tmp_path: Path) -> None:
    store = _cell(tmp_path)
    later = NOW + timedelta(days=1)
    first = dict(first_recipe="side-window")
    before = store.current()
    assert check_ready(before, later, recipe="side-window", **first) == []
    # not taught yet: only its own parts are missing, each with the command that makes it, in the order to run them
    assert check_ready(before, later, recipe="door-window", **first) == [
        "teaching of recipe door-window: missing; run `cellctl teach --recipe door-window`",
        "pixel_map of recipe door-window: missing; run `cellctl calibrate nine-point --recipe door-window`",
    ]
    _teach(store, "door-window", -400.0)
    cal = store.current()
    assert cal is not None and check_ready(cal, later, recipe="door-window", **first) == []
    assert cal.taught("door-window").T0[1, 3] == cal.taught().T0[1, 3] - 400.0  # its own T0, the first's kept
    assert cal.part("camera", "door-window") is cal.part("camera")  # the cell's parts are shared
    # the file holds it under recipes and reads back the same
    data = json.loads((tmp_path / f"set-{cal.version:06d}.json").read_text())
    assert set(data["recipes"]) == {"door-window"} and data["recipes"]["door-window"]["teaching"]["values"]["recipe"] == "door-window"
    assert load_calibration_set(tmp_path / f"set-{cal.version:06d}.json") == cal
    assert store.history()[-1]["recipes"] == {"door-window": {"teaching": "ok", "pixel_map": "ok"}}


def test_a_new_hand_eye_makes_every_recipes_teaching_stale(tmp_path: Path) -> None:
    store = _cell(tmp_path)
    _teach(store, "door-window", -400.0)
    cur = store.current()
    assert cur is not None
    he = make_part("hand_eye", values=VALUES["hand_eye"], method="test", when=NOW + timedelta(hours=1), valid_days=90.0,
                   inputs={"camera": cur.part("camera").id})  # type: ignore[union-attr]  # fmt: skip
    store.commit("hand_eye", he, now=NOW)
    problems = check_ready(store.current(), NOW + timedelta(days=1), recipe="door-window", first_recipe="side-window")
    assert problems == [
        "teaching of recipe door-window: computed with hand_eye "
        f"{cur.part('hand_eye').id}, but the set now holds hand_eye {he.id}; run `cellctl teach --recipe door-window` again"  # type: ignore[union-attr]
    ]


def test_a_teaching_stored_for_another_recipe_is_refused(tmp_path: Path) -> None:
    store = _cell(tmp_path)
    _teach(store, "door-window", -400.0, taught_for="side-window")
    problems = check_ready(store.current(), NOW + timedelta(days=1), recipe="door-window", first_recipe="side-window")
    assert problems == ["teaching of recipe door-window: taught for recipe side-window, not door-window; run `cellctl teach --recipe door-window`"]
    # a set written before recipes had their own teaching records none: it is the first recipe's
    assert check_ready(store.current(), NOW + timedelta(days=1), recipe="side-window", first_recipe="side-window") == []
