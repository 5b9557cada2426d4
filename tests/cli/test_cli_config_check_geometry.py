"""`cellctl config check` refuses a cell whose geometry no cycle can work with, naming the setting and the fix.

On copies of config/sim.toml and config/hardware.example.toml (hosts on 127.0.0.1): an alignment spot or sweep in
the opening, a `[vision.gap]` window that leaves the image, a wall normal pointing back at the robot, an opening
beyond the robot's reach. The figures are worked by hand below; for the first two the twin is the truth: the
refused setting's cycle fails on a glass installed within tolerance (or reads no wall), one just accepted installs.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from config_check_support import ROOT
from config_check_support import check as _check
from config_check_support import refused as _refused
from config_check_support import shipped_copy as _copy
from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

from cellctl.config import CellConfig
from cellctl.config.loader import ConfigError
from cellctl.sim.world import nominal_world


# By hand, both files: the opening is x in [-2000, 0], y in [0, 1500] of T (corner radius 30 mm); the lens
# fx = fy = 5250 px at 400 mm (0.07619 mm/px), the image 2048 x 2048 px, the corner at (cx, cy) = (1024, 1024) px.
# [vision.gap]: border_margin_px = 12, min_points = 150; process.inspect.nominal_gap_mm = 5 (65.6 px).
# The glass's corner lies 65.6 px left of and below the opening's, the real lens's within 40 px of (1024, 1024):
# its right edge's window keeps 150 px inside (v <= 2035) while 1024 + 40 + 65.6 + start + 149 <= 2035, start <= 756.4.
LAST_START_PX = 756.0


@pytest.mark.parametrize("which", ["sim", "hardware"])
def test_the_shipped_geometry_passes_the_check(tmp_path: Path, capsys: pytest.CaptureFixture[str], which: str) -> None:
    rc, err = _check(capsys, _copy(tmp_path, which))
    assert rc == 0, err


# --- F1: the alignment reads the wall where the opening is


@pytest.mark.parametrize("which", ["sim", "hardware"])
def test_a_cells_own_alignment_spot_in_the_opening_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str], which: str) -> None:
    spots = "spots_mm = [[-100.0, 100.0], [-500.0, -60.0], [60.0, 300.0], [60.0, 1200.0], [-1000.0, 1560.0], [-2060.0, 750.0]]"
    if which == "sim":  # (-100, 100): inside the opening, 100 mm from its corner and clear of the 30 mm arc
        cfg = _copy(tmp_path, which, (("spots_mm = [[-1500.0, -60.0],", "spots_mm = [[-100.0, 100.0],"),))
    else:  # the example leaves [process.align] out (the defaults' spots)
        cfg = _copy(tmp_path, which, extra=f"\n[process.align]\n{spots}\n")
    text = _refused(capsys, cfg)
    assert "process.align.spots_mm[0] [-100, 100] lies in the opening (2000 x 1500 mm" in text
    assert "move it onto the wall" in text and "recipes[" not in text


def test_a_sweep_leg_across_the_opening_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Corner 2 (60, 1200) to corner 3 (-2100, 1200): both on the wall, the leg runs along y = 1200 through the opening.
    edits = (('mode = "stop_and_go"', 'mode = "on_the_fly"'),
             ("path_mm = [[-1500.0, -100.0], [60.0, -60.0], [60.0, 1200.0], [60.0, -60.0]]",
              "path_mm = [[-1500.0, -100.0], [60.0, -60.0], [60.0, 1200.0], [-2100.0, 1200.0]]"))  # fmt: skip
    text = _refused(capsys, _copy(tmp_path, "sim", edits))
    assert "process.align.sweep.path_mm: the leg from corner 2 to 3 passes [" in text and "in the opening" in text


async def test_the_twin_reads_no_wall_at_the_refused_spot_and_its_cycle_fails(tmp_path: Path) -> None:
    """The refused setting, let past the check, fails the twin's cycle: its laser finds no wall at (-100, 100)."""
    spots = ((-100.0, 100.0), *sim_config().process.align.spots_mm[1:])
    with pytest.raises(ConfigError, match=re.escape("process.align.spots_mm[0] [-100, 100] lies in the opening")):
        sim_config(**{"process.align": {"spots_mm": [list(s) for s in spots]}})
    good = sim_config()
    bad = good.model_copy(update={"process": good.process.model_copy(
        update={"align": good.process.align.model_copy(update={"spots_mm": spots})})})  # fmt: skip
    assert nominal_world(bad.sim.world).in_opening([-100.0, 100.0])[0]  # the twin's car body: no wall there
    rec = await _twin_cycle(tmp_path, bad, "f1")
    assert rec["state"] == "failed" and "spot 0 gave no distance" in str(rec["error"]), rec


# --- F2: the inspection's window along the edges leaves the image


@pytest.mark.parametrize("which", ["sim", "hardware"])
def test_a_gap_window_off_the_image_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str], which: str) -> None:
    old = "start_px = 440.0 " if which == "sim" else "start_px = 440.0    "  # the [vision.gap] line of each file
    text = _refused(capsys, _copy(tmp_path, which, ((old, "start_px = 1100.0"),)))
    # 1024 - 40 - 65.6 - 12 = 906 px left of the glass's corner to the border: a window from 1100 px has none of it
    assert "vision.gap.start_px = 1100 and length_px = 560 put the top edge's window 1100 to 1660 px left" in text
    assert "as little as 0 px" in text and "vision.gap.min_points = 150" in text
    assert f"lower vision.gap.start_px to at most {LAST_START_PX:g}" in text


def test_the_last_start_accepted_is_the_one_worked_by_hand(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, err = _check(capsys, _copy(tmp_path, "sim", (("start_px = 440.0 ", f"start_px = {LAST_START_PX} "),)))
    assert rc == 0, err
    text = _refused(capsys, _copy(tmp_path, "sim", (("start_px = 440.0 ", f"start_px = {LAST_START_PX + 1} "),)))
    assert "the right edge's window" in text and "as little as 149 px" in text


def test_a_window_shorter_than_the_points_it_needs_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = _refused(capsys, _copy(tmp_path, "sim", (("length_px = 560.0 ", "length_px = 100.0 "),)))
    assert "vision.gap.length_px = 100 gives each edge's window 101 px" in text and "at least 149" in text


def test_a_recipes_own_window_off_the_image_is_refused_by_its_name(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    recipe = 'description = "2000 x 1500 mm side-window glass"'
    cfg = _copy(tmp_path, "hardware", ((recipe, recipe + "\n[process.recipes.vision.gap]\nstart_px = 1900.0"),))
    text = _refused(capsys, cfg)
    assert "process.recipes[0] (side-window): vision.gap.start_px = 1900 and length_px = 560" in text
    assert "of its own" not in text  # the recipe's own setting, named as such


def test_an_arc_recipes_window_is_not_its_inspection(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The door window's 150 mm corner is inspected on its arcs (cellctl.vision.arc_gap): [vision.gap] is not read."""
    old = "[process.recipes.align]                    # the laser's spots and sweep around this opening (in its T0)"
    rc, err = _check(capsys, _copy(tmp_path, "sim", ((old, "[process.recipes.vision.gap]\nstart_px = 1900.0\n" + old),)))
    assert rc == 0, err


@pytest.mark.parametrize(("start_px", "accepted", "says"), [
    (1100.0, False, "has only 0 px inside the image"),  # the window wholly off the image
    (870.0, False, "min top edge points"),  # 1014.7 (the twin's cx) - 12 - 870 + 1 = 134 px of the opening's edge
    (LAST_START_PX, True, ""),
])  # fmt: skip
async def test_the_twin_installs_and_inspects_as_the_check_says(tmp_path: Path, start_px: float, accepted: bool, says: str) -> None:
    """What the check refuses fails the twin's inspection of a glass installed within tolerance, naming the setting;
    the last start it accepts inspects."""
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data["vision"]["gap"]["start_px"] = start_px
    try:
        CellConfig.model_validate(data)
    except ValueError:
        assert not accepted
    else:
        assert accepted
    good = sim_config()
    config = good.model_copy(update={"vision": good.vision.model_copy(
        update={"gap": good.vision.gap.model_copy(update={"start_px": start_px})})})  # fmt: skip
    rec = await _twin_cycle(tmp_path, config, f"f2-{start_px:g}")
    tol = config.process.tolerance
    true = rec["true_error"]
    assert all(abs(true[k]) < tol.position_mm for k in ("dx_mm", "dy_mm", "dz_mm")), true  # the glass sits well
    assert all(abs(true[k]) < tol.orientation_deg for k in ("drx_deg", "dry_deg", "drz_deg")), true
    if accepted:
        assert rec["state"] == "done" and rec["part_ok"] is True, rec
    else:
        assert rec["state"] == "failed" and says in rec["error"], rec
        assert f"vision.gap.start_px = {start_px:g}" in rec["error"] or "set vision.gap.start_px" in rec["error"], rec


# --- F6: the opening's wall faces the robot, and the robot reaches it


@pytest.mark.parametrize("which", ["sim", "hardware"])
def test_a_wall_normal_pointing_at_the_robot_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str], which: str) -> None:
    cfg = _copy(tmp_path, which, (("wall_normal = [1.0, 0.0, 0.0]", "wall_normal = [-1.0, 0.0, 0.0]"),))
    text = _refused(capsys, cfg)
    # corner (1700, -1000, 1800) - reach centre (0, 0, 780) = (1700, -1000, 1020); its dot with (-1, 0, 0) is -1700
    assert "layout.opening.wall_normal = [-1, 0, 0] points back at the robot" in text
    assert "[1700, -1000, 1020] mm from layout.robot.reach_centre_mm" in text and "dot product is -1700 mm" in text
    assert "flip its sign (wall_normal = [1, 0, 0])" in text


@pytest.mark.parametrize("which", ["sim", "hardware"])
def test_an_up_that_puts_the_opening_out_of_reach_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str], which: str) -> None:
    text = _refused(capsys, _copy(tmp_path, which, (("up = [0.0, 0.0, 1.0]", "up = [0.0, 0.0, -1.0]"),)))
    # T: z = (1, 0, 0), y = -up = (0, 0, 1), x = y cross z = (0, 1, 0). The corner x = -2000, y = 1500 of T is at
    # (1700, -3000, 3300), |(1700, -3000, 2520)| = 4271 mm from the reach centre; the laser reads at most
    # 3100 + 450 + |(44, -40, 90 + 250)| = 3100 + 450 + 345 = 3895 mm from it.
    assert np.isclose(np.linalg.norm([1700.0, -3000.0, 2520.0]), 4271.0, atol=0.5)
    assert "layout.opening.up = [0, 0, -1]" in text and "lower-left corner at [1700, -3000, 3300] mm" in text
    assert "4271 mm from layout.robot.reach_centre_mm" in text and "(345 mm from the wrist centre)" in text
    assert "check up's sign" in text


def test_a_recipes_flipped_wall_normal_is_refused_by_its_name(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old = "corner_position_mm = [1700.0, -600.0, 1650.0]"
    text = _refused(capsys, _copy(tmp_path, "sim", ((old, old + "\nwall_normal = [-1.0, 0.0, 0.0]"),)))
    assert "process.recipes[1] (door-window): opening.wall_normal = [-1, 0, 0] points back at the robot" in text


def test_a_too_small_opening_is_named_once_where_the_file_has_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A hardware file has no [sim.world]: the opening's error names [layout.opening] alone."""
    cfg = _copy(tmp_path, "hardware", (("width_mm = 2000.0\nheight_mm = 1500.0", "width_mm = 2.0\nheight_mm = 1.5"),))
    text = _refused(capsys, cfg)
    assert "1 problem(s)" in text and "layout.opening: corner_radius_mm is larger than half" in text
    assert "sim." not in text


async def _twin_cycle(workdir: Path, config: CellConfig, key: str) -> dict[str, Any]:
    """One side-window cycle of the simulated cell (oracle calibration) with ``config``: its record."""
    async with running_service(workdir, config) as service, api_client(service) as client:
        await to_execute(client)
        r = await client.post("/cycle?wait=true&timeout_s=120", json={"recipe": "side-window", "part_id": key},
                              headers={**AUTH, "Idempotency-Key": key})  # fmt: skip
        assert r.status_code in (200, 201), r.text
        return dict(r.json())
