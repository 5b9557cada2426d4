"""A closed loop learnt by a cellctl that keyed loops by the calibration set's version keeps its offset after the
upgrade to loops keyed by the recipe's parts, as long as the set in use is the one it was learnt under (it used to
reset once, and the next installs went in with the bias the loop had taken out); another set still resets it.
The loop learns a known constant bias of the cell's results, the truth here."""

from __future__ import annotations

from pathlib import Path

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.events import EventHub
from cellctl.cell.packml import PackMLMachine
from cellctl.cell.quality_loop import InstallQualityLoop, calibration_key
from cellctl.config import load_config
from cellctl.domain import InstallDeviation
from cellctl.store import AsyncCellStore

ROOT = Path(__file__).resolve().parents[2]
BIAS_MM = 0.12  # every result 0.12 mm off in x


async def test_a_loop_learnt_under_the_set_version_keeps_its_offset_under_the_same_set(tmp_path: Path) -> None:
    config = load_config(ROOT / "config" / "sim.toml")
    store = await AsyncCellStore.open(tmp_path / "cell.db")
    try:
        loop = InstallQualityLoop(config, store, AlarmManager(PackMLMachine(), robot_moving=lambda: False), EventHub())
        recipe = loop.first_recipe
        for k in range(12):  # as the older cellctl fed it: under the set's version, "7"
            offset = loop.offset_for_next(recipe, {"version": 7})
            seen = InstallDeviation(BIAS_MM - offset["dx_mm"], 0.0, 0.0, 0.0, 0.0, 0.0)  # it takes the offset out
            await loop.after_cycle(k + 1, seen, recipe=recipe, calibration="7", applied=offset)
        learnt = loop.offset_for_next(recipe, {"version": 7})["dx_mm"]
        assert 0.05 < learnt <= BIAS_MM + 1e-9, learnt  # most of the bias
        same_set = {"version": 7, "parts": {"camera": "c1", "hand_eye": "h1", "laser": "l1", "teaching": "t1"}}
        assert calibration_key(same_set).startswith("parts-")
        assert loop.offset_for_next(recipe, same_set)["dx_mm"] == learnt  # the set it was learnt under
        other_set = {"version": 8, "parts": {**same_set["parts"], "laser": "l2"}}
        assert loop.offset_for_next(recipe, other_set)["dx_mm"] == 0.0  # a new laser calibration: learnt anew
    finally:
        await store.close()
