"""Teaching one recipe never removes or replaces another recipe's teaching and nine-point map, whatever the order of
[[process.recipes]]: a teaching written in the first's place moves the one there, taught for another recipe (its
``values.recipe``), with its map under that recipe's name, unchanged; older sets (a teaching recording no recipe,
the first's) read and are replaced as before. The set is read back from its JSON files."""

from __future__ import annotations

import json
from datetime import timedelta
from pathlib import Path
from typing import Any

from calib_test_support import NOW
from calib_test_support import commit_teaching as teach
from calib_test_support import store_with_common_parts as cell

from cellctl.calibration.calibration_set import CalibrationStore, parts_of
from cellctl.calibration.readiness import check_ready

LATER = NOW + timedelta(days=1)


def in_file(store: CalibrationStore) -> dict[str, Any]:
    return json.loads((store.root / (store.root / "current").read_text().strip()).read_text())  # type: ignore[no-any-return]


def test_teaching_the_recipe_now_first_moves_the_others_teaching_under_its_name(tmp_path: Path) -> None:
    store = cell(tmp_path / "reordered")
    teach(store, None, "side-window", 0.0)  # taught while it was first
    teach(store, "door-window", "door-window", -400.0)
    side = in_file(store)["parts"]
    # the door window now listed first and taught (`cellctl teach --recipe door-window` writes in the first's place)
    teach(store, None, "door-window", -380.0, when=NOW + timedelta(hours=1), nine_point=False)
    data = in_file(store)
    assert data["recipes"]["side-window"] == {"teaching": side["teaching"], "pixel_map": side["pixel_map"]}  # as they were
    assert data["parts"]["teaching"]["values"]["recipe"] == "door-window" and data["parts"]["pixel_map"] is None
    cal = store.current()
    assert cal is not None
    for first in ("door-window", "side-window"):  # in either order, each reads its own
        assert check_ready(cal, LATER, recipe="side-window", first_recipe=first) == []
        assert cal.taught(parts_of(cal, "side-window", first)).T0[1, 3] == 0.0
        assert cal.taught(parts_of(cal, "door-window", first)).T0[1, 3] == -380.0
    assert check_ready(cal, LATER, recipe="door-window", first_recipe="door-window") == [
        "pixel_map: missing; run `cellctl calibrate nine-point`"
    ]  # taught again: its map follows

    # the side window taught again under its name since: the older one in the first's place is not moved over it
    store = cell(tmp_path / "newer-own")
    teach(store, None, "side-window", 0.0)
    teach(store, "side-window", "side-window", 7.0, when=NOW + timedelta(hours=1))
    own = in_file(store)["recipes"]["side-window"]
    teach(store, None, "door-window", -380.0, when=NOW + timedelta(hours=2))
    assert in_file(store)["recipes"]["side-window"] == own
    cal = store.current()
    assert cal is not None and check_ready(cal, LATER, recipe="side-window", first_recipe="door-window") == []
    assert cal.taught(parts_of(cal, "side-window", "door-window")).T0[1, 3] == 7.0

    # an older set: a teaching recording no recipe (the first's) is read as the first's and taught again in place
    store = cell(tmp_path / "older")
    teach(store, None, None, 0.0)
    cal = store.current()
    assert cal is not None and check_ready(cal, LATER, recipe="side-window", first_recipe="side-window") == []
    teach(store, None, "side-window", 2.0, when=NOW + timedelta(hours=1))
    data = in_file(store)
    assert data["recipes"] == {} and data["parts"]["teaching"]["values"]["recipe"] == "side-window"
    cal = store.current()
    assert cal is not None and check_ready(cal, LATER, recipe="side-window", first_recipe="side-window") == []


def test_a_recipe_no_longer_first_read_in_the_first_place_is_named_in_its_fixes(tmp_path: Path) -> None:
    """`cellctl calibrate nine-point` alone is the first recipe's (now the door window's), not the side window's."""
    store = cell(tmp_path)
    teach(store, None, "side-window", 0.0, nine_point=False)
    teach(store, "door-window", "door-window", -400.0)
    assert check_ready(store.current(), LATER, recipe="side-window", first_recipe="door-window") == [
        "pixel_map of recipe side-window: missing; run `cellctl calibrate nine-point --recipe side-window`"
    ]
    assert check_ready(store.current(), LATER, recipe="side-window", first_recipe="side-window") == [
        "pixel_map: missing; run `cellctl calibrate nine-point`"
    ]
