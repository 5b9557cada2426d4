"""A recipe's teaching written last is the one its cycles, its nine-point job, readiness, `cellctl calibrate status` and
the simulated cell's self-commissioning use, after [[process.recipes]] is reordered or a recipe renamed, whatever the
dates (a teaching dated ahead of the clock, taught while the PC's clock ran fast, or a recompute of an older capture);
and a refusal names the recipe's own command. Truth: the y (mm) each teaching was taught with, and the service's own
verdict (CalibrationSetSource, as GET /status gives it)."""

from __future__ import annotations

import tomllib
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
from calib_test_support import commit_teaching, store_with_common_parts

from cellctl.calibration.calibration_set import CalibrationStore, RecipeParts, taught_for
from cellctl.calibration.readiness import check_ready
from cellctl.calibration.source import CalibrationSetSource
from cellctl.cell.recipe_gate import cycle_refusal
from cellctl.cli import main
from cellctl.commissioning.auto import parts_needed
from cellctl.commissioning.plans import plan_nine_point
from cellctl.config import CellConfig, parse_config

ROOT = Path(__file__).resolve().parents[2]
NOW = datetime.now(timezone.utc).replace(microsecond=0)  # parts dated now: in date


def _config_text(order: tuple[int, int], rename: dict[str, str] | None = None) -> str:
    """config/sim.toml with its two recipes (side window, door window) in ``order``, names changed by ``rename``."""
    text = (ROOT / "config" / "sim.toml").read_text()
    start = text.index("[[process.recipes]]")
    second = text.index("[[process.recipes]]", start + 1)
    end = text.index("\n[sim]", second)
    blocks = [text[start:second], text[second:end]]
    for old, new in (rename or {}).items():
        blocks = [b.replace(f'name = "{old}"', f'name = "{new}"') for b in blocks]
    return text[:start] + blocks[order[0]] + blocks[order[1]] + text[end:]


def _config(order: tuple[int, int], rename: dict[str, str] | None = None) -> CellConfig:
    return parse_config(tomllib.loads(_config_text(order, rename)))


def _cycle_y(store: CalibrationStore, config: CellConfig, recipe: str) -> float:
    return float(CalibrationSetSource(store, config).cycle_calibration(recipe).taught.T0[1, 3])


def test_the_teaching_written_last_is_used_though_an_earlier_one_is_dated_later(tmp_path: Path) -> None:
    store = store_with_common_parts(tmp_path, NOW)
    commit_teaching(store, None, "side-window", 0.0, when=NOW)
    commit_teaching(store, "door-window", "door-window", -400.0, when=NOW + timedelta(hours=2))  # the PC's clock ran ahead
    config = _config((1, 0))  # the door window listed first now, the clock right again
    assert config.default_recipe == "door-window"
    commit_teaching(store, None, "door-window", -380.0, when=NOW)  # `cellctl teach` (the first's), and its map
    cal = store.current()
    assert cal is not None and "door-window" not in cal.recipes  # one teaching per recipe
    assert _cycle_y(store, config, "door-window") == -380.0 and _cycle_y(store, config, "side-window") == 0.0
    centre = sum(p[1, 3] for p in plan_nine_point(config, cal, recipe="door-window").poses) / 9
    assert abs(centre + 380.0) < 1e-6
    assert check_ready(cal, NOW + timedelta(hours=3), recipe="door-window", first_recipe="door-window") == []

    # the side window, no longer first, taught again under its name: its older one leaves the first's place
    commit_teaching(store, "side-window", "side-window", 5.0, when=NOW - timedelta(days=1))  # from an older capture
    cal = store.current()
    assert cal is not None and taught_for(cal.parts.teaching) == "door-window"
    assert _cycle_y(store, config, "side-window") == 5.0 and _cycle_y(store, config, "door-window") == -380.0


class _Jobs:
    """What auto-commissioning reads of the job manager."""

    def __init__(self, store: CalibrationStore, config: CellConfig) -> None:
        self.store, self.config = store, config

    def current_calibration(self):  # type: ignore[no-untyped-def]
        return self.store.current()


@pytest.mark.parametrize("case", ["renamed", "reordered"])
def test_calibrate_status_and_self_commissioning_agree_with_the_service_on_the_first_recipe(
    tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]
) -> None:
    store = store_with_common_parts(tmp_path / "cal", NOW)
    if case == "renamed":  # the door window, taught while first, renamed: the new name was never taught
        commit_teaching(store, None, "door-window", -400.0, when=NOW)
        commit_teaching(store, "side-window", "side-window", 0.0, when=NOW)
        text = _config_text((1, 0), {"door-window": "door-window-v2"})
    else:  # the side window taught while first, the door window under its name; the door window listed first: ready
        commit_teaching(store, None, "side-window", 0.0, when=NOW)
        commit_teaching(store, "door-window", "door-window", -400.0, when=NOW)
        text = _config_text((1, 0))
    path = tmp_path / "cell.toml"
    path.write_text(text)
    config = parse_config(tomllib.loads(text))
    service = CalibrationSetSource(store, config).problems()
    rc = main(["calibrate", "status", "--config", str(path), "--store", str(store.root)])
    out = capsys.readouterr().out
    needed = [str(n) for n in parts_needed(_Jobs(store, config))]  # type: ignore[arg-type]
    if case == "renamed":
        assert service and rc == 1 and "ready for production" not in out, (service, out)
        assert "teaching of recipe door-window-v2: missing" in out
        assert needed == ["teaching", "pixel_map"], needed  # the first recipe's: door-window-v2
    else:
        assert service == [] and rc == 0 and "ready for production" in out, (service, out)
        assert needed == [], needed  # nothing taught again at start


def test_a_refused_cycle_names_the_recipes_own_command_after_a_reorder(tmp_path: Path) -> None:
    store = store_with_common_parts(tmp_path, NOW)
    commit_teaching(store, None, "side-window", 0.0, when=NOW, nine_point=False)  # taught while first, no map yet
    commit_teaching(store, "door-window", "door-window", -400.0, when=NOW)
    source = CalibrationSetSource(store, _config((1, 0)))
    refusal = cycle_refusal(source, "side-window")  # what REST 409, OPC UA and Modbus 908 carry
    assert refusal is not None and "run `cellctl calibrate nine-point --recipe side-window`" in refusal, refusal


def test_a_set_from_before_one_teaching_per_recipe_says_which_of_its_two_it_uses(tmp_path: Path) -> None:
    """A set an earlier release left with the side window's teaching in both places (taught while first with the
    clock ahead, then again under its name after a reorder): readiness warns, naming the one used and the fix."""
    store = store_with_common_parts(tmp_path, NOW)
    commit_teaching(store, None, "side-window", 0.0, when=NOW + timedelta(hours=6))  # dated ahead
    commit_teaching(store, "door-window", "door-window", -400.0, when=NOW)
    cal = store.current()
    assert cal is not None and cal.parts.teaching is not None
    again = cal.parts.teaching.model_copy(update={"id": "teaching-again", "calibrated_utc": NOW})
    legacy = cal.model_copy(update={"recipes": {**cal.recipes, "side-window": RecipeParts(teaching=again)}})
    warnings: list[str] = []
    check_ready(legacy, NOW + timedelta(hours=7), recipe="side-window", first_recipe="door-window", warnings=warnings)
    (line,) = [w for w in warnings if "two teachings" in w]
    assert line.startswith("teaching of recipe side-window: two teachings") and "run `cellctl teach --recipe side-window`" in line
    assert f"({(NOW + timedelta(hours=6)):%Y-%m-%d %H:%M} UTC)" in line  # the one read: the later dated
